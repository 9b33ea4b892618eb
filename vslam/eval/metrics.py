"""Trajectory error metrics: alignment, absolute trajectory error (ATE) and relative pose error (RPE).

Definitions follow Sturm et al., "A Benchmark for the Evaluation of RGB-D SLAM Systems", IROS 2012,
Sec. VI: with ground truth ``Q_i`` and estimate ``P_i`` (both ``T_world_cam``),

* ATE (eq. 3-4): ``F_i = Q_i^-1 S P_i`` after the least-squares alignment ``S`` (Umeyama 1991),
  reported as the translation norm ``||trans(F_i)|| = ||q_i - (s R p_i + t)||``;
* RPE (eq. 1-2): ``E_i = (Q_i^-1 Q_{i+d})^-1 (P_i^-1 P_{i+d})``, reported as ``||trans(E_i)||``
  (metres) and ``angle(rot(E_i))`` (degrees).

The numbers equal evo's ``metrics.APE``/``metrics.RPE`` (checked in ``tests/eval``).
Everything is vectorized over poses.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from vslam.errors import GeometryError, TrajectoryError
from vslam.geometry.lie import inv_se3
from vslam.geometry.umeyama import umeyama

ALIGN_MODES = ("none", "se3", "sim3", "scale", "origin")


@dataclass(frozen=True)
class ErrorStats:
    """Summary statistics of an error array (``std`` is the population standard deviation)."""

    rmse: float
    mean: float
    median: float
    std: float
    min: float
    max: float
    sse: float
    count: int

    @classmethod
    def of(cls, errors: np.ndarray) -> "ErrorStats":
        e = np.asarray(errors, dtype=float).reshape(-1)
        if len(e) == 0:
            nan = float("nan")
            return cls(nan, nan, nan, nan, nan, nan, nan, 0)
        sq = e * e
        return cls(
            rmse=float(np.sqrt(sq.mean())), mean=float(e.mean()), median=float(np.median(e)),
            std=float(e.std()), min=float(e.min()), max=float(e.max()), sse=float(sq.sum()), count=len(e),
        )

    def to_dict(self) -> dict[str, float]:
        return asdict(self)


def rotation_angle(R: np.ndarray) -> np.ndarray:
    """Rotation angle (radians, in ``[0, pi]``) of ``(..., 3, 3)`` rotation matrices.

    ``atan2(|vee(R - R^T)| / 2, (trace(R) - 1) / 2)``, accurate near 0 and pi, unlike ``arccos``.
    """
    R = np.asarray(R, dtype=float)
    w = np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1)
    sin = 0.5 * np.linalg.norm(w, axis=-1)
    cos = 0.5 * (np.trace(R, axis1=-2, axis2=-1) - 1.0)
    return np.arctan2(sin, cos)


def path_lengths(positions: np.ndarray) -> np.ndarray:
    """Accumulated distance ``(N,)`` along ``(N, 3)`` positions, starting at 0."""
    step = np.linalg.norm(np.diff(positions, axis=0), axis=1)
    return np.concatenate([[0.0], np.cumsum(step)])


@dataclass(frozen=True)
class Alignment:
    """The similarity ``x_gt = s R x_est + t`` applied to the estimate."""

    mode: str
    R: np.ndarray
    t: np.ndarray
    s: float

    @property
    def T_gt_est(self) -> np.ndarray:
        """``4x4`` Sim(3) matrix ``[[s R, t], [0, 1]]``."""
        T = np.eye(4)
        T[:3, :3] = self.s * self.R
        T[:3, 3] = self.t
        return T

    def apply(self, T_world_cam: np.ndarray) -> np.ndarray:
        """Aligned poses: ``R_a R_i`` and ``s R_a t_i + t_a`` (rotations stay orthonormal)."""
        out = np.array(T_world_cam, dtype=float, copy=True)
        out[:, :3, :3] = self.R @ out[:, :3, :3]
        out[:, :3, 3] = self.s * out[:, :3, 3] @ self.R.T + self.t
        return out


def align(
    T_est: np.ndarray, T_gt: np.ndarray, mode: str = "se3", n_first: int | None = None
) -> Alignment:
    """Least-squares alignment of the estimate's positions onto ground truth.

    ``mode``: ``none`` (identity), ``se3`` (Umeyama without scale), ``sim3`` (with scale),
    ``scale`` (scale only, as evo's ``correct_only_scale``), ``origin`` (first pose onto first pose).
    ``n_first`` uses only the first ``n_first`` matched poses to estimate the alignment.

    Raises:
        TrajectoryError: unknown mode or too few / degenerate (collinear) poses for Umeyama.
    """
    if mode not in ALIGN_MODES:
        raise TrajectoryError(f"unknown alignment {mode!r} (use one of {', '.join(ALIGN_MODES)})")
    n = len(T_est) if n_first is None or n_first <= 0 else min(int(n_first), len(T_est))
    if mode == "none":
        return Alignment(mode, np.eye(3), np.zeros(3), 1.0)
    if mode == "origin":
        T = T_gt[0] @ inv_se3(T_est[0])
        return Alignment(mode, T[:3, :3], T[:3, 3], 1.0)
    try:
        R, t, s = umeyama(T_est[:n, :3, 3], T_gt[:n, :3, 3], with_scale=mode in ("sim3", "scale"))
    except GeometryError as exc:
        raise TrajectoryError(
            f"cannot align with {mode} using {n} matched poses: {exc}; use more poses "
            "(--align-first, --max-diff) or --align none"
        ) from None
    if mode == "scale":
        return Alignment(mode, np.eye(3), np.zeros(3), s)
    return Alignment(mode, R, t, s)


def ate_errors(T_est: np.ndarray, T_gt: np.ndarray) -> np.ndarray:
    """Absolute translation errors ``(N,)``: ``||t_gt_i - t_est_i||`` (poses already aligned)."""
    return np.linalg.norm(T_gt[:, :3, 3] - T_est[:, :3, 3], axis=1)


def ate_rotation_errors_deg(T_est: np.ndarray, T_gt: np.ndarray) -> np.ndarray:
    """Absolute rotation errors ``(N,)`` in degrees: ``angle(R_gt_i^T R_est_i)``."""
    return np.degrees(rotation_angle(np.swapaxes(T_gt[:, :3, :3], -1, -2) @ T_est[:, :3, :3]))


def rpe_pairs(
    T_world_cam: np.ndarray,
    delta: float = 1,
    unit: str = "frames",
    all_pairs: bool = False,
    rel_tol: float = 0.1,
) -> np.ndarray:
    """Index pairs ``(M, 2)`` ``(i, j)`` separated by ``delta`` frames or metres of path.

    * frames: ``j = i + delta`` for ``i = 0, delta, 2 delta, ...`` (every ``i`` with ``all_pairs``);
    * m: consecutive segments of at least ``delta`` metres of travelled path; with ``all_pairs``,
      for every ``i`` the ``j > i`` whose path distance is nearest ``delta``, kept when within
      ``rel_tol * delta``. (The same pairs as evo's ``filters.filter_pairs_by_*``.)
    """
    n = len(T_world_cam)
    if unit in ("frames", "f"):
        d = int(delta)
        if d < 1 or d != delta:
            raise TrajectoryError(f"RPE delta must be a positive whole number of frames, got {delta}")
        if all_pairs:
            i = np.arange(max(n - d, 0))
        else:
            i = np.arange(0, n, d)[:-1] if n else np.zeros(0, dtype=int)
            i = i[i + d < n]
        return np.stack([i, i + d], axis=1).astype(int)
    if unit not in ("m", "meters", "metres"):
        raise TrajectoryError(f"unknown RPE delta unit {unit!r} (use frames or m)")
    if delta <= 0:
        raise TrajectoryError(f"RPE delta must be positive, got {delta} m")
    dist = path_lengths(T_world_cam[:, :3, 3])
    if all_pairs:
        i = np.arange(n - 1)
        target = dist[i] + delta
        k = np.searchsorted(dist, target, side="left")
        lo = np.maximum(k - 1, i + 1)
        hi = np.minimum(np.maximum(k, i + 1), n - 1)
        # Nearest of the two neighbours; on a tie argmin takes the earlier index.
        e_lo = np.abs(dist[lo] - dist[i] - delta)
        e_hi = np.abs(dist[hi] - dist[i] - delta)
        j = np.where(e_hi < e_lo, hi, lo)
        j = np.maximum(np.searchsorted(dist, dist[j], side="left"), i + 1)  # first of equal distances
        err = np.abs(dist[j] - dist[i] - delta)
        keep = err <= rel_tol * delta
        return np.stack([i[keep], j[keep]], axis=1).astype(int)
    ids = [0]
    while True:
        i = ids[-1]
        j = int(np.searchsorted(dist, dist[i] + delta, side="left"))
        j = max(j, i + 1)
        while j > i + 1 and dist[j - 1] - dist[i] >= delta:
            j -= 1
        while j < n and dist[j] - dist[i] < delta:
            j += 1
        if j >= n:
            break
        ids.append(j)
    ids_arr = np.asarray(ids, dtype=int)
    return np.stack([ids_arr[:-1], ids_arr[1:]], axis=1)


def rpe_errors(
    T_est: np.ndarray, T_gt: np.ndarray, pairs: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Relative pose errors for index ``pairs (M, 2)``: translation (m) and rotation angle (deg).

    ``E = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j)`` (Sturm et al. 2012, eq. 1).
    """
    if len(pairs) == 0:
        return np.zeros(0), np.zeros(0)
    i, j = pairs[:, 0], pairs[:, 1]
    Q_rel = inv_se3(T_gt[i]) @ T_gt[j]
    P_rel = inv_se3(T_est[i]) @ T_est[j]
    E = inv_se3(Q_rel) @ P_rel
    return np.linalg.norm(E[:, :3, 3], axis=1), np.degrees(rotation_angle(E[:, :3, :3]))
