"""ATE of several trajectories under ONE alignment (sessions mapped into a common frame).

Multi-session mapping (``vslam map``) claims every session's trajectory lies in one common frame;
aligning each session on its own would hide an error between them. Here all frames of all
sessions are aligned to their ground truths at once (Umeyama, :func:`vslam.eval.metrics.align`)
and the position RMSE is reported overall and per session under that single alignment.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vslam.errors import TrajectoryError
from vslam.eval.metrics import align
from vslam.trajectory import Trajectory, associate_timestamps


@dataclass(frozen=True)
class JointAte:
    rmse: float  # over every frame of every trajectory [m]
    per_name: dict[str, float]  # each trajectory's RMSE under the same alignment [m]
    frames: int


def joint_ate(estimates: dict[str, Trajectory], truths: dict[str, Trajectory], mode: str = "se3",
              max_diff: float = 1e-4) -> JointAte:
    """``estimates[name]`` against ``truths[name]`` (``T_world_cam``), ONE ``mode`` alignment for all.
    Every estimated pose must have a ground-truth pose within ``max_diff`` s (else
    :class:`TrajectoryError` naming the trajectory)."""
    est, ref, names = [], [], []
    for name, traj in estimates.items():
        gt = truths[name]
        i_est, i_gt = associate_timestamps(traj.timestamps, gt.timestamps, max_diff)
        if len(i_est) != len(traj):
            raise TrajectoryError(f"{name}: {len(traj) - len(i_est)} of {len(traj)} poses have no ground truth "
                                  f"within {max_diff} s")
        est.append(traj.T_world_cam[i_est])
        ref.append(gt.T_world_cam[i_gt])
        names += [name] * len(i_est)
    E, G = np.concatenate(est), np.concatenate(ref)
    err = np.linalg.norm(align(E, G, mode).apply(E)[:, :3, 3] - G[:, :3, 3], axis=1)
    who = np.array(names)
    per = {n: float(np.sqrt(np.mean(err[who == n] ** 2))) for n in dict.fromkeys(names)}
    return JointAte(float(np.sqrt(np.mean(err ** 2))), per, len(err))
