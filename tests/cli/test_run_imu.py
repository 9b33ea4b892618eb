"""``vslam run --sensor *-inertial`` and ``--imu FILE``: the sensor names, one-line errors (exit 2)
for what is missing, and an RGB-D sequence of the renderer with its IMU passed as ``--imu``."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from vslam.cli import main
from vslam.cli.run_cmd import ALL_SENSORS
from vslam.datasets.synthetic import SyntheticConfig, SyntheticImuConfig, render_sequence
from vslam.inertial import sensors


def cli(capsys, *argv) -> tuple[int, str, str]:
    rc = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return rc, out, err


def one_error(err: str, rc: int, *words: str) -> None:
    assert "Traceback" not in err, err
    assert rc == 2, (rc, err)
    lines = [ln for ln in err.splitlines() if ln.startswith("vslam ")]
    assert len(lines) == 1, err
    for w in words:
        assert w in lines[0], (w, lines[0])


def test_sensor_names():
    assert ALL_SENSORS == sensors.ALL_SENSORS   # the CLI spells them out (no numpy at parser time)
    assert sensors.split_sensor("rgbd-inertial") == ("rgbd", True)
    with pytest.raises(Exception, match="unknown sensor"):
        sensors.split_sensor("lidar-inertial")


@pytest.fixture(scope="module")
def seq(tmp_path_factory) -> Path:
    """75 synthetic RGB-D frames (320x240, the renderer's loop in 2.5 s) with its IMU in ``imu0/``
    (EuRoC CSV, Kalibr camchain-imucam.yaml, noise and biases on)."""
    cfg = SyntheticConfig(n_frames=75, width=320, height=240, fx=262.5, fy=262.5, cx=159.5, cy=119.5,
                          stereo=False, seed=3)
    return render_sequence(tmp_path_factory.mktemp("vi") / "seq", cfg, imu=SyntheticImuConfig(seed=0))


def test_errors_name_what_is_missing(capsys, tmp_path, seq):
    rc, _, err = cli(capsys, "run", seq, "--sensor", "rgbd-inertial", "-o", tmp_path / "a", "--no-progress")
    one_error(err, rc, "no IMU data", "--imu")                 # a TUM folder: its imu0/ is not looked for
    rc, _, err = cli(capsys, "run", seq, "--sensor", "rgbd", "--imu", seq / "imu0" / "data.csv",
                     "-o", tmp_path / "b", "--no-progress")
    one_error(err, rc, "--imu", "inertial")
    rc, _, err = cli(capsys, "run", seq, "--sensor", "rgbd-inertial", "--imu", tmp_path / "none.csv",
                     "-o", tmp_path / "c", "--no-progress")
    one_error(err, rc, "IMU file not found")
    lone = tmp_path / "lone"
    lone.mkdir()
    (lone / "data.csv").write_text((seq / "imu0" / "data.csv").read_text())
    rc, _, err = cli(capsys, "run", seq, "--sensor", "rgbd-inertial", "--imu", lone / "data.csv",
                     "-o", tmp_path / "d", "--no-progress")
    one_error(err, rc, "no IMU calibration", "camchain-imucam.yaml")


def test_rgbd_inertial_with_imu_file(capsys, tmp_path, seq):
    """The renderer's world is z up (its IMU's gravity is -z): the run's world z axis is within 2
    degrees of it (measured 1.19: a 1.07 s window of a gentle path with a noisy IMU) and the
    trajectory as good as plain RGB-D's (measured ATE 0.0180 m; rgbd alone 0.0175 m)."""
    from vslam.eval.evaluate import evaluate_trajectories
    from vslam.trajectory import read_tum

    out = tmp_path / "run"
    rc, stdout, err = cli(capsys, "run", seq, "--sensor", "rgbd-inertial", "--imu", seq / "imu0" / "data.csv",
                          "-o", out, "--no-progress")
    assert rc == 0, err
    assert "IMU initialized at frame" in stdout
    stats = json.loads((out / "stats.json").read_text())
    assert stats["sensor"] == "rgbd-inertial" and stats["imu_initialized"] and stats["tracked"] == 75
    assert stats["imu_init_time_s"] <= 1.5
    ev = evaluate_trajectories(read_tum(out / "trajectory.txt"), read_tum(seq / "groundtruth.txt"), align="se3")
    assert ev.ate_rmse <= 0.025
    assert np.degrees(np.arccos(np.clip(ev.alignment.R[2, 2], -1, 1))) <= 2.0


def test_rgbd_inertial_localizes_with_its_imu(capsys, tmp_path, seq):
    """``vslam localize --sensor rgbd-inertial --imu FILE`` in the run's gravity-aligned map: every
    frame localized, all but the first ones tracked from the IMU's prediction (measured 72), ATE
    measured 0.0200 m (the visual localization of the same frames, ``--sensor rgbd``: 0.0297 m);
    bound 1.5x."""
    from vslam.eval.evaluate import evaluate_trajectories
    from vslam.trajectory import read_tum

    imu = seq / "imu0" / "data.csv"
    assert cli(capsys, "run", seq, "--sensor", "rgbd-inertial", "--imu", imu, "-o", tmp_path / "map",
               "--no-progress")[0] == 0
    rc, stdout, err = cli(capsys, "localize", tmp_path / "map", seq, "--sensor", "rgbd-inertial", "--imu", imu,
                          "-o", tmp_path / "loc", "--no-progress")
    assert rc == 0, err
    assert "75/75 frames localized" in stdout
    s = json.loads((tmp_path / "loc" / "stats.json").read_text())
    assert s["imu_used"] is True and s["imu_only_frames"] == 0 and s["imu_predicted_frames"] >= 70   # measured 72
    ev = evaluate_trajectories(read_tum(tmp_path / "loc" / "trajectory.txt"), read_tum(seq / "groundtruth.txt"),
                               align="se3")
    assert ev.ate_rmse <= 0.03
