"""Array containers for bundle-adjustment problems and results (no solver knowledge here).

A problem holds keyframe poses ``T_world_cam (K, 4, 4)`` with ids ``kf_ids (K,)``, points
``X_world (P, 3)`` with ids ``pt_ids (P,)`` and ``M`` observations given by *ids*
(``obs_kf``, ``obs_pt``), undistorted pixels ``obs_uv (M, 2)`` with a per-observation pixel std
``obs_sigma`` (ORB-SLAM: ``scale_factor ** octave``), and optionally the rectified right-image
column ``obs_u_right`` (stereo) or the measured depth ``obs_depth`` (RGB-D), NaN where absent.
``fixed_kf_ids`` are keyframes held constant (the gauge).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from vslam.errors import GeometryError
from vslam.geometry.camera import PinholeCamera


def _index_of(ids: np.ndarray, query: np.ndarray, what: str, order: np.ndarray | None = None) -> np.ndarray:
    """Position of each ``query`` id in ``ids`` (vectorized); raises if one is unknown.

    ``order``: ``argsort(ids)`` when the caller has it, ``None`` when ``ids`` is already sorted.
    """
    if len(query) == 0:
        return np.zeros(0, np.int64)
    if len(ids) == 0:
        raise GeometryError(f"BA problem references {what} ids {query[:5].tolist()} but has no {what}s")
    sorted_ids = ids if order is None else ids[order]
    pos = np.clip(np.searchsorted(sorted_ids, query), 0, len(ids) - 1)
    idx = pos if order is None else order[pos]
    bad = ids[idx] != query
    if np.any(bad):
        raise GeometryError(f"BA problem references unknown {what} ids, e.g. {query[bad][:5].tolist()}")
    return idx


def _sort_order(ids: np.ndarray) -> np.ndarray | None:
    """``argsort(ids)``, or ``None`` when ``ids`` is already strictly increasing (the usual case)."""
    return None if np.all(ids[1:] > ids[:-1]) else np.argsort(ids, kind="stable")


def _checked_rows(ids: np.ndarray, query: np.ndarray, rows: np.ndarray | None) -> np.ndarray | None:
    """``rows`` when they are the positions of ``query`` in ``ids`` (``ids[rows] == query``), else None."""
    if rows is None or len(query) == 0:
        return None
    rows = np.asarray(rows)
    if (rows.dtype != np.int64 or rows.shape != query.shape or rows.min() < 0 or rows.max() >= len(ids)
            or not np.array_equal(ids[rows], query)):
        return None
    return rows


@dataclass
class BAProblem:
    """A bundle-adjustment problem as flat arrays (see the module docstring)."""

    camera: PinholeCamera
    kf_ids: np.ndarray
    T_world_cam: np.ndarray
    pt_ids: np.ndarray
    X_world: np.ndarray
    obs_kf: np.ndarray
    obs_pt: np.ndarray
    obs_uv: np.ndarray
    obs_sigma: np.ndarray | None = None
    obs_u_right: np.ndarray | None = None
    obs_depth: np.ndarray | None = None
    fixed_kf_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    # optional hint: the rows ``(kf_index(obs_kf), pt_index(obs_pt))`` when the builder has them; checked
    # (``kf_ids[rows] == obs_kf``, one gather) instead of searched, ignored when wrong; None once used
    obs_rows: tuple[np.ndarray, np.ndarray] | None = field(default=None, repr=False, compare=False)

    def __post_init__(self) -> None:
        self.kf_ids = np.asarray(self.kf_ids, dtype=np.int64).reshape(-1)
        self.T_world_cam = np.asarray(self.T_world_cam, dtype=float).reshape(-1, 4, 4)
        self.pt_ids = np.asarray(self.pt_ids, dtype=np.int64).reshape(-1)
        self.X_world = np.asarray(self.X_world, dtype=float).reshape(-1, 3)
        self.obs_kf = np.asarray(self.obs_kf, dtype=np.int64).reshape(-1)
        self.obs_pt = np.asarray(self.obs_pt, dtype=np.int64).reshape(-1)
        self.obs_uv = np.asarray(self.obs_uv, dtype=float).reshape(-1, 2)
        m = len(self.obs_kf)
        self.obs_sigma = np.ones(m) if self.obs_sigma is None else np.asarray(self.obs_sigma, float).reshape(-1)
        self.obs_u_right = np.full(m, np.nan) if self.obs_u_right is None else np.asarray(self.obs_u_right, float).reshape(-1)
        self.obs_depth = np.full(m, np.nan) if self.obs_depth is None else np.asarray(self.obs_depth, float).reshape(-1)
        self.fixed_kf_ids = np.asarray(self.fixed_kf_ids, dtype=np.int64).reshape(-1)
        self.validate()

    @property
    def num_keyframes(self) -> int:
        return len(self.kf_ids)

    @property
    def num_points(self) -> int:
        return len(self.pt_ids)

    @property
    def num_observations(self) -> int:
        return len(self.obs_kf)

    def validate(self) -> None:
        """Check shapes, ids and finiteness; raise :class:`GeometryError` naming the bad array."""
        k, p, m = len(self.kf_ids), len(self.pt_ids), len(self.obs_kf)
        if self.T_world_cam.shape[0] != k:
            raise GeometryError(f"BA problem: {k} kf_ids but T_world_cam has {self.T_world_cam.shape[0]} poses")
        if self.X_world.shape[0] != p:
            raise GeometryError(f"BA problem: {p} pt_ids but X_world has {self.X_world.shape[0]} points")
        for name in ("obs_pt", "obs_uv", "obs_sigma", "obs_u_right", "obs_depth"):
            if getattr(self, name).shape[0] != m:
                raise GeometryError(f"BA problem: {name} has {getattr(self, name).shape[0]} rows, obs_kf has {m}")
        self._kf_order, self._pt_order = _sort_order(self.kf_ids), _sort_order(self.pt_ids)
        # strictly increasing ids (order None) are unique
        if ((self._kf_order is not None and len(np.unique(self.kf_ids)) != k)
                or (self._pt_order is not None and len(np.unique(self.pt_ids)) != p)):
            raise GeometryError("BA problem: kf_ids and pt_ids must be unique")
        if not (np.all(np.isfinite(self.T_world_cam)) and np.all(np.isfinite(self.X_world)) and np.all(np.isfinite(self.obs_uv))):
            raise GeometryError("BA problem: T_world_cam, X_world and obs_uv must be finite (found NaN/inf)")
        if np.any(~(self.obs_sigma > 0)):
            raise GeometryError("BA problem: obs_sigma must be > 0 for every observation")
        if np.any(np.isfinite(self.obs_u_right) & np.isfinite(self.obs_depth)):
            raise GeometryError("BA problem: an observation has both obs_u_right and obs_depth; give one")
        if np.any(np.isfinite(self.obs_u_right)) and not (self.camera.baseline and self.camera.baseline > 0):
            raise GeometryError("BA problem: obs_u_right given but the camera has no stereo baseline")
        self._rows = None
        self.kf_index(self.fixed_kf_ids)
        # the rows of every observation, resolved once (the solver and the write-back ask again)
        hint, self.obs_rows = self.obs_rows, None
        kf_rows = _checked_rows(self.kf_ids, self.obs_kf, None if hint is None else hint[0])
        pt_rows = _checked_rows(self.pt_ids, self.obs_pt, None if hint is None else hint[1])
        rows = (self.kf_index(self.obs_kf) if kf_rows is None else kf_rows,
                self.pt_index(self.obs_pt) if pt_rows is None else pt_rows)
        self._rows = (self.obs_kf, self.obs_pt, rows[0], rows[1])
        pairs = rows[0] * max(p, 1) + rows[1]
        # a count per (keyframe, point) cell when that table is small (local BA), else a sort
        twice = (np.bincount(pairs, minlength=k * p).max(initial=0) > 1 if k * p <= 8 * m + (1 << 16)
                 else len(np.unique(pairs)) != m)
        if twice:
            raise GeometryError("BA problem: a point is observed twice by the same keyframe; keep one observation")

    def kf_index(self, ids: np.ndarray) -> np.ndarray:
        """Rows of ``T_world_cam`` for keyframe ``ids``."""
        rows = getattr(self, "_rows", None)  # absent on an unpickled problem: resolved afresh
        if rows is not None and ids is rows[0] and ids is self.obs_kf:
            return rows[2].copy()
        order = getattr(self, "_kf_order", None) if hasattr(self, "_kf_order") else _sort_order(self.kf_ids)
        return _index_of(self.kf_ids, np.asarray(ids, np.int64).reshape(-1), "keyframe", order)

    def pt_index(self, ids: np.ndarray) -> np.ndarray:
        """Rows of ``X_world`` for point ``ids``."""
        rows = getattr(self, "_rows", None)
        if rows is not None and ids is rows[1] and ids is self.obs_pt:
            return rows[3].copy()
        order = getattr(self, "_pt_order", None) if hasattr(self, "_pt_order") else _sort_order(self.pt_ids)
        return _index_of(self.pt_ids, np.asarray(ids, np.int64).reshape(-1), "point", order)


@dataclass
class BAResult:
    """Optimized poses and points (same ids and order as the problem) and diagnostics.

    ``inlier_mask (M,)`` is the chi-square test after optimization (and positive depth).
    Costs are ``sum chi2`` over the inlier observations of the initial and final estimate;
    ``initial_rms_px`` / ``final_rms_px`` are the RMS pixel reprojection errors of the inliers.
    """

    kf_ids: np.ndarray
    T_world_cam: np.ndarray
    pt_ids: np.ndarray
    X_world: np.ndarray
    inlier_mask: np.ndarray
    initial_cost: float
    final_cost: float
    initial_rms_px: float
    final_rms_px: float
    iterations: int
    build_time_s: float
    solve_time_s: float
    time_s: float
    solver: str

    def poses(self) -> dict[int, np.ndarray]:
        """``{kf_id: T_world_cam}``."""
        return {int(i): T for i, T in zip(self.kf_ids, self.T_world_cam)}

    def points(self) -> dict[int, np.ndarray]:
        """``{pt_id: X_world}``."""
        return {int(i): X for i, X in zip(self.pt_ids, self.X_world)}

    def summary(self) -> dict:
        return {
            "solver": self.solver, "keyframes": int(len(self.kf_ids)), "points": int(len(self.pt_ids)),
            "observations": int(len(self.inlier_mask)), "inliers": int(self.inlier_mask.sum()),
            "initial_cost": self.initial_cost, "final_cost": self.final_cost,
            "initial_rms_px": self.initial_rms_px, "final_rms_px": self.final_rms_px,
            "iterations": self.iterations, "build_time_s": self.build_time_s,
            "solve_time_s": self.solve_time_s, "time_s": self.time_s,
        }
