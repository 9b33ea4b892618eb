"""Vision fails, the IMU carries on (issue #28 item 8), on REAL EuRoC MH_01 (80 frames, 20 Hz):
frames 50-59 (0.5 s) black in both cameras, after the IMU initialization (stereo-inertial at frame
25, mono-inertial at frame 40). Each black frame takes the IMU prediction as its pose
(``frontend.tracking.imu_only_max_s``, 1 s), and visual tracking resumes at frame 60 in the same map
segment, against the local map from the IMU-predicted pose.

Measured on this machine (deterministic backend), with the visual-inertial local BA, the full VI-BA
after the initialization and the tracker's inertial pose optimization (#28 items 4-6; before them
stereo-inertial 0.0032 m, mono-inertial 0.0050 m):

| run, frames 50-59 black | poses | imu_only_frames | SE(3) ATE | segments |
|---|---|---|---|---|
| stereo-inertial | 80/80 | 10 | 0.0028 m (0.0029 without the blackout) | 1 |
| mono-inertial | 80/80 | 10 | 0.0038 m (0.0041 before the wider monocular local map of #24 round 8, 0.0042 before the final full VI-BA) | 1 |
| stereo | 70/80 (the 10 black frames lost) | | 0.0032 m over the 70 | 1 |

The bounds sit a little above these (other CPUs' rounding); stereo-inertial's is the issue's goal
(ATE <= 0.01 m with 10 black frames).
"""
from __future__ import annotations

import os
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from vslam.eval.evaluate import evaluate_trajectories

MH01 = "euroc_mh01_vi_80"
BLACK = range(50, 60)


def blacked_out(src: Path, dst: Path, frames) -> Path:
    """A copy of the EuRoC folder ``src`` (links, not copies) whose ``frames`` are black in both cameras."""
    shutil.copytree(src, dst, copy_function=os.symlink)
    for cam in ("cam0", "cam1"):
        names = sorted((dst / "mav0" / cam / "data").iterdir())
        for i in frames:
            img = cv2.imread(str(names[i].resolve()), cv2.IMREAD_UNCHANGED)
            names[i].unlink()
            cv2.imwrite(str(names[i]), np.zeros_like(img))
    return dst


@pytest.fixture(scope="module")
def runs(shared_data, tmp_path_factory):
    """``{sensor: RunResult}`` on MH_01 with frames 50-59 black."""
    from vslam.api import run_path

    seq = blacked_out(shared_data / MH01, tmp_path_factory.mktemp("blackout") / "mh01", BLACK)
    out = {sensor: run_path(seq, tmp_path_factory.mktemp(sensor) / "run", sensor=sensor, prefetch="none")
           for sensor in ("stereo-inertial", "mono-inertial", "stereo")}
    out["off"] = run_path(seq, tmp_path_factory.mktemp("off") / "run", sensor="stereo-inertial", prefetch="none",
                          overrides=["frontend.tracking.imu_only_max_s=0"])
    return out


@pytest.fixture(scope="module")
def gt(shared_data):
    from vslam.datasets import open_dataset

    return open_dataset(shared_data / MH01, sensor="stereo").ground_truth()


def _times(shared_data, frames) -> np.ndarray:
    from vslam.datasets import open_dataset

    return np.asarray(open_dataset(shared_data / MH01, sensor="stereo").timestamps)[list(frames)]


@pytest.mark.shared
@pytest.mark.parametrize("sensor, max_ate", [("stereo-inertial", 0.005), ("mono-inertial", 0.008)])
def test_black_frames_are_posed_by_the_imu(runs, gt, shared_data, sensor, max_ate):
    r = runs[sensor]
    s = r.stats
    assert s["imu_init_frame"] < BLACK[0]                          # initialized before the blackout
    assert len(r.trajectory) == s["frames"] == s["tracked"] == 80  # every frame has a pose
    assert s["imu_only_frames"] == len(BLACK) and s["lost"] == 0   # measured 10 (the black ones)
    assert s["map_segments"] == s["segments"] == 1                 # tracking resumed in the same segment
    black_t = _times(shared_data, BLACK)
    assert np.isin(black_t, r.trajectory.timestamps).all()
    ate = evaluate_trajectories(r.trajectory, gt, align="se3").ate_rmse
    assert ate <= max_ate                                          # measured 0.0028 / 0.0038 (goal 0.01)
    # imu_states.csv: one row per frame from the initialization on, the black frames flagged
    from vslam.inertial.states_csv import read_imu_states

    st = read_imu_states(r.output_dir / "imu_states.csv")
    assert len(st["timestamp"]) == 80 - s["imu_init_frame"]
    assert np.array_equal(st["timestamp"][st["imu_only"] > 0], black_t)
    speed = np.linalg.norm(np.column_stack([st["vx"], st["vy"], st["vz"]]), axis=1)
    assert 0.05 < np.median(speed) < 2.0                           # MH_01 hand-held: 2.1 m in 4 s


@pytest.mark.shared
def test_plain_stereo_loses_the_black_frames(runs, gt):
    r = runs["stereo"]
    assert r.stats["lost"] == len(BLACK) and len(r.trajectory) == 80 - len(BLACK)
    assert "imu_only_frames" not in r.stats and not (r.output_dir / "imu_states.csv").exists()
    inertial = evaluate_trajectories(runs["stereo-inertial"].trajectory, gt, align="se3").ate_rmse
    assert inertial <= r.stats["ate_rmse"] + 0.0005                # measured 0.0028 vs 0.0032 (over 70 poses)


@pytest.mark.shared
def test_imu_only_can_be_switched_off(runs):
    """``frontend.tracking.imu_only_max_s=0``: stereo-inertial loses the black frames as stereo does."""
    s = runs["off"].stats
    assert s["imu_only_frames"] == 0 and s["lost"] == len(BLACK) and len(runs["off"].trajectory) == 80 - len(BLACK)


@pytest.mark.shared
def test_report_plots_velocity_and_biases(runs, tmp_path):
    """``vslam report`` on the stereo-inertial run folder: the IMU figure and the IMU-only count."""
    from vslam.cli import main

    out = tmp_path / "report.html"
    assert main(["report", str(runs["stereo-inertial"].output_dir), "-o", str(out)]) == 0
    html = out.read_text()
    assert "<h2>IMU: velocity and biases</h2>" in html and 'alt="IMU velocity and biases"' in html
    assert "posed by the IMU alone</td><td>10<" in html
