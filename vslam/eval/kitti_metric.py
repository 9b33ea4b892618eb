"""The KITTI odometry benchmark metric (Geiger et al., "Are we ready for Autonomous Driving?
The KITTI Vision Benchmark Suite", CVPR 2012; devkit ``evaluate_odometry.cpp``).

For every first frame ``i = 0, step, 2 step, ...`` and every segment length ``L`` (default
100, 200, ..., 800 m of ground-truth path), ``j`` is the first frame whose ground-truth path
distance from ``i`` exceeds ``L``; the segment error is ``E = (P_i^-1 P_j)^-1 (Q_i^-1 Q_j)``
and contributes ``||trans(E)|| / L`` and ``angle(rot(E)) / L`` (the angle by atan2, which unlike
the devkit's acos stays accurate for small angles of the slightly non-orthonormal rotations in
KITTI files; the two differ by ~1e-4 relative). The reported numbers are the
means over all segments of all lengths: translation in percent and rotation in degrees per
100 m (the devkit's deg/m times 100). Shorter ``lengths`` make the metric usable on short runs.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from vslam.errors import TrajectoryError
from vslam.eval.metrics import path_lengths, rotation_angle

KITTI_LENGTHS = (100.0, 200.0, 300.0, 400.0, 500.0, 600.0, 700.0, 800.0)


@dataclass(frozen=True)
class KittiResult:
    """KITTI devkit errors: overall and per segment length."""

    t_err_percent: float
    r_err_deg_per_100m: float
    num_segments: int
    lengths: tuple[float, ...]
    per_length: dict[float, dict[str, float]] = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {
            "t_err_percent": self.t_err_percent,
            "r_err_deg_per_100m": self.r_err_deg_per_100m,
            "num_segments": self.num_segments,
            "lengths": list(self.lengths),
            "per_length": {f"{k:g}": v for k, v in self.per_length.items()},
        }


def kitti_segment_errors(
    T_est: np.ndarray, T_gt: np.ndarray, lengths: tuple[float, ...] = KITTI_LENGTHS, step: int = 10
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """All devkit segments: ``(t_err (M,) m/m, r_err (M,) rad/m, length (M,) m)``."""
    if len(T_est) != len(T_gt):
        raise TrajectoryError(f"KITTI metric needs matched poses, got {len(T_est)} and {len(T_gt)}")
    dist = path_lengths(T_gt[:, :3, 3])
    first = np.arange(0, len(T_gt), max(int(step), 1))
    t_all, r_all, l_all = [], [], []
    for length in lengths:
        # Devkit lastFrameFromSegmentLength: first j with dist[j] > dist[i] + L.
        last = np.searchsorted(dist, dist[first] + length, side="right")
        ok = last < len(dist)
        i, j = first[ok], last[ok]
        if len(i) == 0:
            continue
        # General inverses, as the devkit: KITTI files hold slightly non-orthonormal rotations.
        delta_gt = np.linalg.solve(T_gt[i], T_gt[j])
        delta_est = np.linalg.solve(T_est[i], T_est[j])
        E = np.linalg.solve(delta_est, delta_gt)
        t_all.append(np.linalg.norm(E[:, :3, 3], axis=1) / length)
        r_all.append(rotation_angle(E[:, :3, :3]) / length)
        l_all.append(np.full(len(i), float(length)))
    if not t_all:
        return np.zeros(0), np.zeros(0), np.zeros(0)
    return np.concatenate(t_all), np.concatenate(r_all), np.concatenate(l_all)


def kitti_odometry_error(
    T_est: np.ndarray, T_gt: np.ndarray, lengths: tuple[float, ...] | None = None, step: int = 10
) -> KittiResult:
    """The KITTI odometry metric of matched ``T_world_cam`` poses (see module docstring).

    Raises:
        TrajectoryError: the ground-truth path is shorter than every segment length.
    """
    lengths = tuple(float(x) for x in (lengths or KITTI_LENGTHS))
    if any(x <= 0 for x in lengths):
        raise TrajectoryError(f"KITTI segment lengths must be positive, got {lengths}")
    t_err, r_err, seg_len = kitti_segment_errors(T_est, T_gt, lengths, step)
    if len(t_err) == 0:
        total = path_lengths(T_gt[:, :3, 3])[-1] if len(T_gt) else 0.0
        raise TrajectoryError(
            f"KITTI metric: the ground-truth path is {total:.1f} m, shorter than every segment length "
            f"{[f'{x:g}' for x in lengths]}; pass shorter --lengths (e.g. 5 10 20)"
        )
    per_length = {
        L: {
            "t_err_percent": float(100 * t_err[seg_len == L].mean()),
            "r_err_deg_per_100m": float(100 * np.degrees(r_err[seg_len == L].mean())),
            "num_segments": int(np.sum(seg_len == L)),
        }
        for L in lengths
        if np.any(seg_len == L)
    }
    return KittiResult(
        t_err_percent=float(100 * t_err.mean()),
        r_err_deg_per_100m=float(100 * np.degrees(r_err.mean())),
        num_segments=len(t_err),
        lengths=lengths,
        per_length=per_length,
    )
