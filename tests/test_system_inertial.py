"""The inertial sensors end to end on REAL EuRoC MH_01 (hand-held excitation, 80 frames, 4 s, 200 Hz
IMU): ``run_path(sensor="mono-inertial" | "stereo-inertial")`` against EuRoC's ground truth (its
world is z up), beside the plain ``stereo`` run of the same frames.

Measured on this machine (deterministic backend; the same numbers every run):

| run | SE(3) ATE | Sim(3) scale | world z vs gravity | IMU initialized |
|---|---|---|---|---|
| mono-inertial | 0.0030 m | 1.0035 | 0.43 deg | frame 40, 2.00 s |
| stereo-inertial | 0.0033 m | 1.0086 | 0.21 deg | frame 25, 1.25 s |
| stereo | 0.0032 m | | (visual world: first camera) | |

The bounds below sit a little above these (for other CPUs' rounding), inside the issue's goals
(#28: mono-inertial SE(3) ATE <= 0.02 m, scale within 5 %, initialized within ~2 s of motion;
stereo-inertial no worse than stereo, world z within 2 degrees of gravity).
"""
from __future__ import annotations

import numpy as np
import pytest

from vslam.eval.evaluate import evaluate_trajectories

MH01 = "euroc_mh01_vi_80"


@pytest.fixture(scope="module")
def runs(shared_data, tmp_path_factory):
    """``{sensor: RunResult}`` for mono-inertial, stereo-inertial and stereo on MH_01."""
    from vslam.api import run_path

    out = {}
    for sensor in ("mono-inertial", "stereo-inertial", "stereo"):
        folder = tmp_path_factory.mktemp(sensor)
        out[sensor] = run_path(shared_data / MH01, folder / "run", sensor=sensor, prefetch="none")
    return out


def gravity_tilt_deg(result, gt) -> float:
    """Angle between the run's world z axis and the ground truth's (up; EuRoC's world is z up),
    through the SE(3) alignment of the trajectory onto the ground truth."""
    R = evaluate_trajectories(result.trajectory, gt, align="se3").alignment.R
    return float(np.degrees(np.arccos(np.clip(R[2, 2], -1.0, 1.0))))


@pytest.fixture(scope="module")
def gt(shared_data):
    from vslam.datasets import open_dataset

    return open_dataset(shared_data / MH01, sensor="stereo").ground_truth()


@pytest.mark.shared
def test_mono_inertial_is_metric_and_gravity_aligned(runs, gt):
    r = runs["mono-inertial"]
    s = r.stats
    assert len(r.trajectory) == s["frames"] == 80                # a pose for every frame
    assert s["sensor"] == "mono-inertial" and s["imu_initialized"]
    assert s["imu_init_time_s"] <= 2.5 and s["imu_init_frame"] <= 50
    assert 0.1 < s["imu_scale"] < 10 and s["gravity"] == [0.0, 0.0, -9.81]
    assert len(s["imu_bias_gyro"]) == len(s["imu_bias_accel"]) == 3
    assert s["imu_predicted_frames"] >= 80 - s["imu_init_frame"] - 1   # the IMU predicted every later frame
    se3 = evaluate_trajectories(r.trajectory, gt, align="se3")
    sim3 = evaluate_trajectories(r.trajectory, gt, align="sim3")
    assert se3.ate_rmse <= 0.005                                  # measured 0.0030 (goal 0.02)
    assert s["ate_rmse"] == pytest.approx(se3.ate_rmse)           # the run evaluated it SE(3) (metric)
    assert abs(sim3.scale - 1.0) <= 0.02                          # measured 1.0035 (goal 5 %)
    assert gravity_tilt_deg(r, gt) <= 1.0                         # measured 0.43


@pytest.mark.shared
def test_stereo_inertial_is_gravity_aligned_and_as_good_as_stereo(runs, gt):
    r, plain = runs["stereo-inertial"], runs["stereo"]
    s = r.stats
    assert len(r.trajectory) == 80 and s["imu_initialized"] and "imu_scale" not in s
    assert s["imu_init_time_s"] <= 1.5                            # measured 1.25 (10 keyframes after 1 s)
    assert gravity_tilt_deg(r, gt) <= 1.0                         # measured 0.21 (goal 2)
    assert s["ate_rmse"] <= plain.stats["ate_rmse"] + 0.0005      # measured 0.0033 vs 0.0032
    assert "imu_initialized" not in plain.stats                   # plain sensors report no IMU


def test_inertial_sensor_needs_the_imu():
    """``System`` with an inertial sensor and no IMU: one error naming what is missing."""
    from vslam.errors import DatasetError
    from vslam.geometry.camera import PinholeCamera
    from vslam.system import System

    cam = PinholeCamera(500.0, 500.0, 320.0, 240.0, 640, 480)
    with pytest.raises(DatasetError, match="mono-inertial needs IMU samples and IMU calibration"):
        System(None, cam, sensor="mono-inertial")
    assert System(None, cam, sensor="mono").inertial is None
