"""One alignment for several trajectories (vslam.eval.joint): a session placed wrongly relative to
the others shows in the joint ATE, though each session alone would align perfectly."""
from __future__ import annotations

import numpy as np
import pytest

from vslam.errors import TrajectoryError
from vslam.eval.joint import joint_ate
from vslam.geometry.lie import make_T, so3_exp
from vslam.trajectory import Trajectory


def _traj(t0: float, offset: np.ndarray) -> Trajectory:
    t = t0 + np.arange(20) * 0.1
    T = np.tile(np.eye(4), (20, 1, 1))
    T[:, 0, 3] = np.linspace(0, 2, 20) + offset[0]
    T[:, 1, 3] = np.sin(t) + offset[1]
    T[:, 2, 3] = 0.1 * t + offset[2]
    return Trajectory(t, T)


def test_one_alignment_sees_a_misplaced_session():
    gt = {"a": _traj(0.0, np.zeros(3)), "b": _traj(5.0, np.array([0.5, -1.0, 0.2]))}
    W = make_T(so3_exp(np.array([0.1, -0.2, 0.3])), np.array([3.0, 1.0, -2.0]))  # the map's own frame
    moved = {k: Trajectory(v.timestamps, W @ v.T_world_cam) for k, v in gt.items()}
    j = joint_ate(moved, gt)
    assert j.frames == 40 and j.rmse < 1e-9 and max(j.per_name.values()) < 1e-9  # one rigid motion: exact
    off = dict(moved)
    off["b"] = Trajectory(moved["b"].timestamps, moved["b"].T_world_cam.copy())
    off["b"].T_world_cam[:, :3, 3] += [0.1, 0.0, 0.0]  # session b 10 cm off the common frame
    j = joint_ate(off, gt)
    # splitting the 10 cm between the two equal-sized sessions (5 cm each) is one feasible alignment,
    # so the least-squares one is at most that; its rotation absorbs part (measured 0.031)
    assert 0.02 < j.rmse <= 0.05 + 1e-9 and min(j.per_name.values()) > 0.01
    alone = joint_ate({"b": off["b"]}, {"b": gt["b"]})  # session b aligned on its own: no error seen
    assert alone.rmse < 1e-9


def test_a_pose_without_ground_truth_is_an_error():
    gt = {"a": _traj(0.0, np.zeros(3))}
    late = {"a": _traj(0.05, np.zeros(3))}  # every stamp 50 ms off
    with pytest.raises(TrajectoryError, match="a: 20 of 20 poses have no ground truth"):
        joint_ate(late, gt)
