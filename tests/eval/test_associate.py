"""Timestamp association (vslam.trajectory.associate_timestamps, as evaluation uses it): nearest within
max_diff, offset, one-to-one, evo parity, no overlap."""
from __future__ import annotations

import numpy as np
import pytest

from vslam.errors import TrajectoryError
from vslam.eval.associate import associate_trajectories
from vslam.trajectory import Trajectory, associate_timestamps


def traj(ts) -> Trajectory:
    ts = np.asarray(ts, dtype=float)
    T = np.tile(np.eye(4), (len(ts), 1, 1))
    T[:, 0, 3] = ts
    return Trajectory(ts, T)


def test_nearest_within_max_diff():
    gt = np.arange(0.0, 1.0, 0.01)  # 100 Hz
    est = np.array([0.004, 0.106, 0.5, 0.5149, 2.0, -0.02])
    i_est, i_gt = associate_timestamps(est[np.argsort(est)], gt, max_diff=0.01)
    est_sorted = np.sort(est)
    np.testing.assert_array_equal(est_sorted[i_est], [0.004, 0.106, 0.5, 0.5149])
    np.testing.assert_array_equal(i_gt, [0, 11, 50, 51])  # 0.5149 -> 0.51 (0.0049 < 0.0051)


def test_offset_is_added_to_estimate():
    gt = np.arange(0.0, 10.0, 0.1)
    est = gt[20:40] - 3.05  # estimate clock is 3.05 s behind
    assert len(associate_timestamps(est, gt, 0.01)[0]) == 0
    i_est, i_gt = associate_timestamps(est, gt, 0.01, offset=3.05)
    np.testing.assert_array_equal(i_est, np.arange(20))
    np.testing.assert_array_equal(i_gt, np.arange(20, 40))


def test_one_to_one_keeps_closest():
    a = np.array([1.000, 1.004, 1.007])  # all nearest to b = 1.005
    b = np.array([0.5, 1.005, 2.0, 3.0, 4.0])
    ia, ib = associate_timestamps(a, b, max_diff=0.01)
    np.testing.assert_array_equal(ia, [1])
    np.testing.assert_array_equal(ib, [1])


def test_tie_goes_to_earlier():
    ia, ib = associate_timestamps(np.array([1.5]), np.array([1.0, 2.0]), max_diff=1.0)
    assert ib.tolist() == [0]


def test_matches_evo_on_random_stamps(evo):
    rng = np.random.default_rng(3)
    gt = np.cumsum(rng.uniform(0.005, 0.015, 3000))
    est = np.sort(rng.uniform(gt[0] - 1, gt[-1] + 1, 700))
    est = est[np.concatenate([[True], np.diff(est) > 0.03])]  # sparse: evo's matches are one-to-one
    ref_ids, est_ids = evo.sync.matching_time_indices(est, gt, 0.004, 0.0)
    i_est, i_gt = associate_timestamps(est, gt, max_diff=0.004)
    np.testing.assert_array_equal(i_est, ref_ids)
    np.testing.assert_array_equal(i_gt, est_ids)
    assert 100 < len(i_est) < len(est)


def test_associate_trajectories_errors():
    with pytest.raises(TrajectoryError, match="no common timestamps between est.txt"):
        associate_trajectories(traj([1.0, 2.0]), traj([10.0, 11.0]), est_name="est.txt")
    with pytest.raises(TrajectoryError, match="same number of poses"):
        associate_trajectories(traj([0, 1, 2]), traj([0, 1]), by_index=True)
    with pytest.raises(TrajectoryError, match="empty"):
        associate_trajectories(traj([]), traj([0, 1]))
    e, g = associate_trajectories(traj([0, 1, 2]), traj([5, 6, 7]), by_index=True)
    assert len(e) == len(g) == 3
