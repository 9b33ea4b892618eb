"""The localizer's IMU state (:class:`vslam.localizer_imu.LocalizerImu`) on the synthetic IMU with exact
ground truth (the renderer's loop, 30 fps, 200 Hz noise-free samples with biases): the velocity from
two localized poses, the prediction, the bridging window, and the map's biases."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from tests.frontend.test_imu_prediction import TIMES, synthetic, truth  # noqa: F401 (the fixture, shared)
from vslam.localizer_imu import LocalizerImu
from vslam.map.io_inertial import map_bias


def test_velocity_from_two_poses_then_prediction_and_bridging(synthetic):
    """No prediction from one pose (no velocity yet); from the second localized pose on, the next
    frame is predicted to 1 um (measured 2.2e-8 m in the predictor's own test: the same kinematics),
    and a frame 0.5 s after the last localized one is bridged to 1e-5 m (the velocity from two exact
    poses is exact to 1e-6 m/s). Past ``max_bridge_s`` nothing is bridged; after ``forget`` nothing
    is predicted until two frames are localized again."""
    imu, calib, bias = synthetic
    T = truth(calib)[0]
    li = LocalizerImu(imu, calib, bias, max_bridge_s=0.6)
    li.localized(TIMES[0], T[0])
    assert li.predict(TIMES[1]) is None and li.bridge(TIMES[1]) is None and not li.velocity_known
    li.localized(TIMES[1], T[1])
    worst = 0.0
    for k in range(2, 10):
        worst = max(worst, float(np.linalg.norm(li.predict(TIMES[k])[:3, 3] - T[k][:3, 3])))
        li.localized(TIMES[k], T[k])
    assert worst < 1e-6
    # a blackout from frame 10 on: frames 10..24 bridged from frame 9 while within 0.6 s
    bridged = {k: li.bridge(TIMES[k]) for k in range(10, 28)}
    ok = [k for k, Tk in bridged.items() if Tk is not None]
    assert ok == [k for k in range(10, 28) if TIMES[k] - TIMES[9] <= 0.6]   # 18 frames at 30 fps
    assert max(np.linalg.norm(bridged[k][:3, 3] - T[k][:3, 3]) for k in ok) < 1e-5
    assert li.n_bridged == len(ok)
    li.forget()
    assert li.predict(TIMES[28]) is None and li.bridge(TIMES[28]) is None


def test_a_long_gap_starts_a_new_state_without_velocity(synthetic):
    """A localized frame more than ``max_bridge_s`` (at least 0.5 s) after the previous one (a
    relocalization after being lost) gives no velocity: the two poses are too far apart to trust
    the bias over the gap."""
    imu, calib, bias = synthetic
    T = truth(calib)[0]
    li = LocalizerImu(imu, calib, bias, max_bridge_s=0.3)
    li.localized(TIMES[0], T[0])
    li.localized(TIMES[20], T[20])          # 0.67 s later
    assert not li.velocity_known and li.predict(TIMES[21]) is None
    li.localized(TIMES[21], T[21])
    assert li.velocity_known and np.linalg.norm(li.predict(TIMES[22])[:3, 3] - T[22][:3, 3]) < 1e-6


def test_map_bias_is_the_median_of_the_keyframes():
    kfs = [SimpleNamespace(extra={"imu_bias": np.r_[0.01 * i, 0, 0, 0.1 * i, 0, 0]}) for i in range(5)]
    kfs.append(SimpleNamespace(extra={}))  # a keyframe without an IMU state
    b = map_bias(kfs)
    np.testing.assert_allclose(b.gyro, [0.02, 0, 0])
    np.testing.assert_allclose(b.accel, [0.2, 0, 0])
    none = map_bias([SimpleNamespace(extra={})])
    assert not np.any(none.gyro) and not np.any(none.accel)
