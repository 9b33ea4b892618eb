"""The IMU in ``vslam localize`` (issue #28 items 1 and 8) on REAL EuRoC MH_01 (80 frames, 20 Hz): the
sequence localized in the stereo-inertial map of the same 80 frames, once as recorded and once with
frames 50-59 (0.5 s) black in both cameras. With ``--sensor stereo-inertial`` the IMU predicts each
frame from the last localized one (velocity from two localized poses, :mod:`vslam.localizer_imu`)
and poses the black frames; the visual localizer loses them.

Measured on this machine under three CPU profiles (default, ``OPENBLAS_CORETYPE=Haswell``,
``SandyBridge`` with ``NUMBA_CPU_NAME=generic`` and one thread; the map: 33 keyframes, ATE 0.0029 m;
the inertial rows are the same under all three, the visual ones move with rounding; with the final
full VI-BA of the mapping run the map's ATE is 0.0027 m and the rows below read 0.0028, 0.0083,
0.0040 (worst black frame 14.0 mm) and 0.0089 m):

| localized with | frames 50-59 | poses | imu_only_frames | SE(3) ATE | worst black frame |
|---|---|---|---|---|---|
| stereo-inertial | as recorded | 80/80 (79 tracked + 1 relocalized) | 0 | 0.0029 m | |
| stereo (visual) | as recorded | 80/80 (77-78 tracked + 2-3 relocalized) | | 0.0042-0.0119 m | |
| stereo-inertial | black | 80/80 (69 + 1, 10 by the IMU) | 10 | 0.0039 m | 13.0 mm |
| stereo (visual) | black | 70/80 (10 lost) | | 0.0044-0.0085 m over the 70 | |

Bounds: about 2x the measured figures (other CPUs' rounding moves the map and with it the
localization: the visual-inertial test of ``test_continue_inertial`` saw 0.0029-0.0051 m from small
map changes), and the issue's blackout goal (ATE <= 0.01 m) for the bridged run.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from tests.test_inertial_blackout import BLACK, MH01, blacked_out
from vslam.eval.evaluate import evaluate_trajectories


@pytest.fixture(scope="module")
def setup(shared_data: Path, tmp_path_factory) -> dict:
    from vslam.api import run_path
    from vslam.datasets import open_dataset

    root = tmp_path_factory.mktemp("localize_inertial")
    run_path(shared_data / MH01, root / "map", sensor="stereo-inertial", prefetch="none")
    black = blacked_out(shared_data / MH01, root / "black", BLACK)
    ds = open_dataset(shared_data / MH01, sensor="stereo")
    return {"root": root, "data": shared_data / MH01, "black": black, "gt": ds.ground_truth(),
            "black_times": np.asarray(ds.timestamps)[list(BLACK)]}


def _localize(setup: dict, data: Path, sensor: str, name: str):
    from vslam.localize import localize_path

    return localize_path(setup["root"] / "map", data, setup["root"] / name, sensor=sensor, prefetch="none")


@pytest.mark.shared
def test_the_imu_poses_black_frames_in_a_visual_inertial_map(setup: dict) -> None:
    """Every frame has a pose, the black ones the IMU's, within the issue's 0.01 m blackout goal."""
    r = _localize(setup, setup["black"], "stereo-inertial", "loc_black")
    s = r.stats
    assert s["imu_used"] is True and s["map_gravity_aligned"] is True
    assert s["frames"] == len(r.trajectory) == 80 and s["lost"] == 0             # every frame has a pose
    assert s["imu_only_frames"] == 10 and s["localized"] == 70                   # exactly the black ones
    assert s["imu_predicted_frames"] >= 60                                       # measured 68
    assert s["ate_rmse"] < 0.008                                                 # measured 0.0039; goal 0.01
    ev = evaluate_trajectories(r.trajectory, setup["gt"])
    black = np.isin(ev.est_aligned.timestamps, setup["black_times"])
    assert black.sum() == 10 and ev.ate_errors[black].max() < 0.025             # measured 13.0 mm
    # the CLI line says what the IMU did
    from vslam.localize import counts_line
    assert "10 posed by the IMU alone, 0 lost" in counts_line(s)


@pytest.mark.shared
def test_without_the_imu_the_black_frames_are_lost(setup: dict) -> None:
    """The visual localizer in the same map: the black frames have no pose."""
    s = _localize(setup, setup["black"], "stereo", "loc_black_visual").stats
    assert "imu_used" not in s or s["imu_used"] is False
    assert s["lost"] == 10 and s["localized"] == 70                              # measured 10 / 70


@pytest.mark.shared
def test_imu_prediction_keeps_the_clean_sequence_accurate(setup: dict) -> None:
    """As recorded, every frame is localized from the IMU's prediction (all but the first two)."""
    r = _localize(setup, setup["data"], "stereo-inertial", "loc")
    s = r.stats
    assert s["localized"] == 80 and s["imu_only_frames"] == 0
    assert s["ate_rmse"] < 0.006                                                 # measured 0.0029
    assert s["imu_predicted_frames"] >= 70                                       # measured 78
    saved = json.loads((setup["root"] / "loc" / "stats.json").read_text())
    assert saved["imu_used"] is True and saved["imu_only_frames"] == 0


@pytest.mark.shared
def test_a_map_without_gravity_localizes_visually_with_a_warning(setup: dict, tmp_path: Path, caplog) -> None:
    """A map that is not gravity-aligned (a visual run's) has no direction to integrate the IMU in:
    the frames are localized visually, said in a warning and ``imu_used`` false; ``--imu`` with a
    visual sensor is a configuration error."""
    import logging
    import shutil

    from vslam.errors import ConfigError
    from vslam.localize import localize_path

    shutil.copytree(setup["root"] / "map", tmp_path / "map")
    path = tmp_path / "map" / "map" / "map.json"
    manifest = json.loads(path.read_text())
    manifest["map_attributes"]["gravity_aligned"] = False
    path.write_text(json.dumps(manifest))
    with caplog.at_level(logging.WARNING, logger="vslam.localize"):
        r = localize_path(tmp_path / "map", setup["data"], tmp_path / "loc", sensor="stereo-inertial", max_frames=5,
                          prefetch="none")
    assert r.stats["imu_used"] is False and "imu_only_frames" not in r.stats and r.stats["localized"] == 5
    assert any("not gravity-aligned" in rec.getMessage() for rec in caplog.records)
    with pytest.raises(ConfigError, match="--imu is read by the inertial sensors only"):
        localize_path(tmp_path / "map", setup["data"], tmp_path / "loc2", sensor="stereo", max_frames=5,
                      imu=setup["data"] / "mav0" / "imu0" / "data.csv")
