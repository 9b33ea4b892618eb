"""``vslam gt`` (the ground truth a run uses, as TUM) and ``vslam eval`` against EuRoC's body-frame
ground truth (issue #25 item 3), on the EuRoC MH_01 slice (body-frame ``state_groundtruth_estimate0``)."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from vslam.cli import main
from vslam.datasets import open_dataset
from vslam.trajectory import read_tum


@pytest.fixture
def euroc(shared_data: Path, tmp_path: Path) -> Path:
    """A copy of the EuRoC slice (tests may move its files)."""
    dst = tmp_path / "mh01"
    shutil.copytree(shared_data / "euroc_mh01_vi_80", dst)
    return dst


def _body(seq: Path) -> Path:
    return seq / "mav0" / "state_groundtruth_estimate0" / "data.csv"


@pytest.mark.parametrize("sensor", ["mono", "stereo"])
def test_gt_writes_the_datasets_ground_truth(euroc: Path, tmp_path: Path, capsys, sensor: str) -> None:
    out = tmp_path / "gt.txt"
    assert main(["gt", str(euroc), "--sensor", sensor, "-o", str(out)]) == 0
    text = capsys.readouterr().out.strip()
    assert text.startswith("80 poses of 80 frames from ") and "state_groundtruth_estimate0" in text
    assert ("rectified" in text) == (sensor == "stereo")
    written, truth = read_tum(out), open_dataset(euroc, sensor=sensor).ground_truth()
    assert len(written) == len(truth) == 80
    np.testing.assert_allclose(written.timestamps, truth.timestamps, atol=1e-6)
    np.testing.assert_allclose(written.T_world_cam, truth.T_world_cam, atol=1e-7)


@pytest.mark.parametrize("name, frame", [("7scenes_redkitchen", "camera"), ("kitti_odometry/sequences/06", "cam0")])
def test_gt_of_7scenes_and_kitti(shared_data: Path, tmp_path: Path, capsys, name: str, frame: str) -> None:
    seq, out = shared_data / name, tmp_path / "gt.txt"
    assert main(["gt", str(seq), "-o", str(out)]) == 0
    assert f"(frame {frame})" in capsys.readouterr().out
    written, truth = read_tum(out), open_dataset(seq).ground_truth()
    np.testing.assert_allclose(written.timestamps, truth.timestamps, atol=1e-6)
    np.testing.assert_allclose(written.positions, truth.positions, atol=1e-7)
    # TUM stores a quaternion: 7-Scenes' not quite orthonormal rotations come back orthonormalized
    np.testing.assert_allclose(written.T_world_cam[:, :3, :3], truth.T_world_cam[:, :3, :3], atol=1e-3)


def test_gt_of_tum_and_refusals(shared_data: Path, euroc: Path, tmp_path: Path, capsys) -> None:
    seq = shared_data / "tum_rgbd_freiburg1_desk_9frames"
    out = tmp_path / "fr1.txt"
    assert main(["gt", str(seq), "-o", str(out)]) == 0
    truth = open_dataset(seq).ground_truth()
    np.testing.assert_allclose(read_tum(out).T_world_cam, truth.T_world_cam, atol=1e-7)
    assert "(frame rgb)" in capsys.readouterr().out
    # never over the ground truth it reads, nor any other file of the sequence
    before = _body(euroc).read_bytes()
    for target in (_body(euroc), euroc / "mav0" / "cam0" / "data.csv"):
        assert main(["gt", str(euroc), "-o", str(target)]) == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith("vslam gt: error:") and "\n" not in err
    assert _body(euroc).read_bytes() == before


def test_eval_converts_euroc_body_ground_truth_to_cam0(euroc: Path, tmp_path: Path, capsys) -> None:
    cam0 = tmp_path / "cam0.txt"
    assert main(["gt", str(euroc), "--sensor", "mono", "-o", str(cam0)]) == 0
    capsys.readouterr()
    converted, raw = tmp_path / "converted.json", tmp_path / "raw.json"
    assert main(["eval", str(_body(euroc)), str(cam0), "--json", str(converted)]) == 0
    said = [line for line in capsys.readouterr().out.splitlines() if "body-frame" in line]
    assert len(said) == 1 and "converted to cam0 with T_BS of" in said[0] and "cam0/sensor.yaml" in said[0]
    good = json.loads(converted.read_text())
    assert good["matched_poses"] == 80 and good["ate_rmse"] < 1e-4 and good["ate_rot_deg_rmse"] < 0.01
    # as it is (the body's poses): the 90-degree rotation between IMU and camera, the lever arm in the ATE
    assert main(["eval", str(_body(euroc)), str(cam0), "--body-to-cam", "none", "--json", str(raw)]) == 0
    assert "body-frame" not in capsys.readouterr().out
    bad = json.loads(raw.read_text())
    assert 89 < bad["ate_rot_deg_rmse"] < 91 and bad["ate_rmse"] > 0.005  # measured 89.94 deg, 0.0078 m
    assert bad["ate_rmse"] > 100 * max(good["ate_rmse"], 1e-6)
    # no sensor.yaml beside it: refused with the fix; naming the file converts again
    yaml = tmp_path / "sensor.yaml"
    shutil.move(euroc / "mav0" / "cam0" / "sensor.yaml", yaml)
    assert main(["eval", str(_body(euroc)), str(cam0)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "body-frame ground truth" in err and "--body-to-cam" in err and "vslam gt" in err
    assert main(["eval", str(_body(euroc)), str(cam0), "--body-to-cam", str(yaml), "--json", str(converted)]) == 0
    assert json.loads(converted.read_text())["ate_rmse"] < 1e-4 and "body-frame" in capsys.readouterr().out
    # a body-frame estimate against the body-frame reference: nothing to convert
    assert main(["eval", str(_body(euroc)), str(_body(euroc))]) == 0
    assert "body-frame" not in capsys.readouterr().out


@pytest.mark.parametrize("sensor", ["mono", "stereo"])
def test_run_with_gt_body_frame_file_converts_it(euroc: Path, sensor: str, caplog) -> None:
    """``vslam run --gt .../state_groundtruth_estimate0/data.csv``: the body poses become the run's camera's."""
    from vslam.datasets.ground_truth import resolve_ground_truth

    ds = open_dataset(euroc, sensor=sensor)
    truth = resolve_ground_truth(ds, _body(euroc))
    assert truth.frame == "cam0 (converted from the body frame)" and truth.file == str(_body(euroc).resolve())
    assert "converted to cam0 with T_BS" in caplog.text
    own = ds.ground_truth()
    np.testing.assert_allclose(truth.trajectory.timestamps, own.timestamps)
    np.testing.assert_allclose(truth.trajectory.T_world_cam, own.T_world_cam, atol=1e-9)
    (euroc / "mav0" / "cam0" / "sensor.yaml").rename(euroc / "sensor.yaml.bak")  # then: skipped, with the fix
    truth = resolve_ground_truth(ds, _body(euroc))
    assert truth.trajectory is None and "no mav0/cam0/sensor.yaml beside it" in truth.problem
    assert "vslam gt SEQUENCE" in truth.problem and "--body-to-cam" not in truth.problem
