"""Each session's trajectory in its component's common frame (step 5 of :mod:`vslam.multisession`).

A session placed in a component by ``S`` (its world -> the common frame: SE(3), Sim(3) monocular)
with its keyframe ids shifted by ``offset`` in the component's map: every frame of its own
``trajectory.txt`` is moved by ``S`` and then by the correction its reference keyframe received
from the merges' BAs, the pose graph and the global BA (:func:`session_trajectory`). The merging
itself is :mod:`vslam.multisession.tree_merge` and :mod:`vslam.multisession.global_opt`.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np


def sim3_poses(S: np.ndarray, T: np.ndarray) -> np.ndarray:
    """Camera poses ``T (N, 4, 4)`` moved by the Sim(3) ``S``: rotation ``R_S R``, centre ``S c``
    (the camera stays rigid, as :func:`vslam.map.append.append_map` moves keyframes)."""
    s = float(np.cbrt(np.linalg.det(S[:3, :3])))
    out = np.array(T, dtype=float, copy=True)
    out[:, :3, :3] = (S[:3, :3] / s) @ out[:, :3, :3]
    out[:, :3, 3] = out[:, :3, 3] @ S[:3, :3].T + S[:3, 3]
    return out


def session_trajectory(slam_map, S: np.ndarray, offset: int, before: dict[int, np.ndarray], folder: Path):
    """The session's ``trajectory.txt`` in the component's common frame: every frame moved by
    ``S``, then by the correction its reference keyframe received in ``slam_map`` (the last keyframe
    at or before the frame; the first for earlier frames): ``T' = (K_after (S * K_before)^-1) (S * T)``.
    ``before``: the session's keyframe poses in its own run (``{kf id: T_world_cam}``)."""
    from vslam.geometry.lie import inv_se3
    from vslam.trajectory import Trajectory, read_tum

    traj = read_tum(Path(folder) / "trajectory.txt")
    T = sim3_poses(S, traj.T_world_cam)
    kf_ids = sorted(k for k in before if (k + offset) in slam_map.keyframes and not slam_map.keyframes[k + offset].bad)
    if not kf_ids:
        return Trajectory(traj.timestamps, T)
    kf_t = np.array([slam_map.keyframes[k + offset].timestamp for k in kf_ids])
    order = np.argsort(kf_t, kind="stable")
    kf_ids, kf_t = [kf_ids[i] for i in order], kf_t[order]
    placed = sim3_poses(S, np.stack([before[k] for k in kf_ids]))
    after = np.stack([slam_map.keyframes[k + offset].T_world_cam for k in kf_ids])
    corrections = after @ inv_se3(placed)
    ref = np.clip(np.searchsorted(kf_t, traj.timestamps + 1e-9, side="right") - 1, 0, len(kf_ids) - 1)
    return Trajectory(traj.timestamps, corrections[ref] @ T)
