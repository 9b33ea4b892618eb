"""Camera pose from 3D-2D correspondences (Perspective-n-Point) with RANSAC and LM refinement.

Minimal solver inside RANSAC: P3P (Kneip et al., CVPR 2011) / AP3P (Ke & Roumeliotis, CVPR 2017)
via OpenCV's ``solvePnPRansac``; refinement: Levenberg-Marquardt on the reprojection error
(``cv2.solvePnPRefineLM``) over the inliers, then the inliers are re-selected and refined again.
On 500 points with 30 % outliers this takes a few milliseconds (see benchmarks/geometry_bench.py).

Failure contract: :func:`solve_pnp` raises :class:`vslam.errors.GeometryError` (fewer than 4
points, NaN/inf, collinear points, no consensus, fewer than ``min_inliers`` inliers); it never
returns ``None``.
"""
from __future__ import annotations

import logging
from typing import Literal

import numpy as np

from vslam.errors import GeometryError
from vslam.geometry.lie import make_T

log = logging.getLogger(__name__)

_FLAGS = {"p3p": "SOLVEPNP_P3P", "ap3p": "SOLVEPNP_AP3P", "epnp": "SOLVEPNP_EPNP", "sqpnp": "SOLVEPNP_SQPNP"}


def project_points(
    T_cam_world: np.ndarray, K: np.ndarray, X_world: np.ndarray, dist: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Pixels ``(N, 2)`` of world points and their camera depths ``z`` ``(N,)`` (radtan if ``dist``)."""
    T = np.asarray(T_cam_world, float)
    X_cam = np.asarray(X_world, float) @ T[:3, :3].T + T[:3, 3]
    z = X_cam[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        xn = X_cam[:, :2] / z[:, None]
    if dist is not None and np.any(np.asarray(dist) != 0):
        k1, k2, p1, p2, k3 = np.r_[np.asarray(dist, float).ravel(), np.zeros(5)][:5]
        x, y = xn[:, 0], xn[:, 1]
        r2 = x * x + y * y
        rad = 1 + k1 * r2 + k2 * r2 * r2 + k3 * r2**3
        xn = np.stack([x * rad + 2 * p1 * x * y + p2 * (r2 + 2 * x * x),
                       y * rad + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y], axis=1)
    K = np.asarray(K, float)
    uv = np.stack([K[0, 0] * xn[:, 0] + K[0, 1] * xn[:, 1] + K[0, 2], K[1, 1] * xn[:, 1] + K[1, 2]], axis=1)
    return uv, z


def _reproj_inliers(T, K, X, x, dist, threshold_px):
    uv, z = project_points(T, K, X, dist)
    err = np.linalg.norm(uv - x, axis=1)
    return (z > 0) & np.isfinite(err) & (err < threshold_px), err


def _to_T(rvec: np.ndarray, tvec: np.ndarray) -> np.ndarray:
    import cv2

    return make_T(cv2.Rodrigues(np.asarray(rvec, float))[0], np.asarray(tvec, float).ravel())


def _refine_lm(T, K, X, x, dist, threshold_px, rounds: int = 2):
    """LM on the inliers of ``T``, re-selecting the inliers after each round."""
    import cv2

    mask, _ = _reproj_inliers(T, K, X, x, dist, threshold_px)
    for _ in range(rounds):
        if mask.sum() < 4:
            break
        rvec = cv2.Rodrigues(T[:3, :3])[0]
        tvec = T[:3, 3].reshape(3, 1).copy()
        rvec, tvec = cv2.solvePnPRefineLM(
            X[mask], x[mask], K, dist, rvec, tvec,
            (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 20, 1e-10),
        )
        T = _to_T(rvec, tvec)
        new, _ = _reproj_inliers(T, K, X, x, dist, threshold_px)
        if np.array_equal(new, mask):
            break
        mask = new
    return T, mask


def solve_pnp(
    X_world: np.ndarray, x: np.ndarray, K: np.ndarray, dist: np.ndarray | None = None,
    T_cam_world_init: np.ndarray | None = None, threshold_px: float = 2.0,
    confidence: float = 0.999, max_iters: int = 300, min_inliers: int = 6,
    method: Literal["p3p", "ap3p", "epnp", "sqpnp"] = "p3p", init_gate: float = 3.0,
    refine_rounds: int = 2,
) -> tuple[np.ndarray, np.ndarray]:
    """``T_cam_world`` from world points and their pixels: RANSAC + Levenberg-Marquardt.

    With ``T_cam_world_init`` (e.g. a constant-velocity prediction while tracking), the guess is
    tried first: LM from it on the points within ``init_gate * threshold_px``; if the refined pose
    keeps at least half of the points as inliers RANSAC is skipped, otherwise RANSAC runs as usual.

    Args:
        X_world: ``(N, 3)`` points in the world frame, ``N >= 4``.
        x: ``(N, 2)`` observed pixels (distorted if ``dist`` is given, ideal otherwise).
        K: 3x3 intrinsics. dist: OpenCV distortion ``(k1, k2, p1, p2, k3)`` or ``None``.
        threshold_px: inlier threshold on the reprojection error, pixels.
        min_inliers: fewer final inliers raise :class:`GeometryError` (capped at ``N``, at least 4).
        method: minimal solver inside RANSAC (``p3p`` is the fastest; ``sqpnp``/``epnp`` also work).
        refine_rounds: LM rounds (each re-selecting the inliers) after the initial guess's gated
            round; 1 when a later refinement follows anyway.

    Returns:
        ``(T_cam_world (4, 4), inlier_mask (N,) bool)``.

    Raises:
        GeometryError: too few / non-finite / collinear points, or no pose with enough inliers.
    """
    import cv2

    X = np.ascontiguousarray(X_world, dtype=np.float64)
    x = np.ascontiguousarray(x, dtype=np.float64)
    K = np.asarray(K, dtype=np.float64)
    if X.ndim != 2 or X.shape[1] != 3 or x.shape != (X.shape[0], 2):
        raise GeometryError(f"solve_pnp needs (N, 3) points and (N, 2) pixels, got {X.shape} and {x.shape}")
    n = X.shape[0]
    if n < 4:
        raise GeometryError(f"solve_pnp needs at least 4 correspondences, got {n}")
    if not (np.all(np.isfinite(X)) and np.all(np.isfinite(x))):
        raise GeometryError("solve_pnp got NaN or inf coordinates; drop those correspondences first")
    if K.shape != (3, 3) or not np.all(np.isfinite(K)):
        raise GeometryError(f"solve_pnp: K must be a finite 3x3 matrix, got {K!r}")
    if method not in _FLAGS:
        raise GeometryError(f"unknown PnP method {method!r}; use one of {sorted(_FLAGS)}")
    sv = np.linalg.svd(X - X.mean(axis=0), compute_uv=False)
    if sv[1] < 1e-9 * max(sv[0], 1e-300):
        raise GeometryError("solve_pnp: the 3D points are collinear (or coincident); the pose is undetermined")
    d = None if dist is None else np.asarray(dist, dtype=np.float64).ravel()
    need = max(4, min(min_inliers, n))  # with only 4-5 points, all of them must agree

    if T_cam_world_init is not None:
        T0 = np.asarray(T_cam_world_init, float)
        if T0.shape != (4, 4) or not np.all(np.isfinite(T0)):
            raise GeometryError(f"solve_pnp: T_cam_world_init must be a finite 4x4 matrix, got shape {T0.shape}")
        gate, _ = _reproj_inliers(T0, K, X, x, d, init_gate * threshold_px)
        if gate.sum() >= need:
            T, mask = _refine_lm(T0, K, X, x, d, init_gate * threshold_px, rounds=1)
            T, mask = _refine_lm(T, K, X, x, d, threshold_px, rounds=refine_rounds)
            if mask.sum() >= max(need, 0.5 * n):
                return T, mask
        log.debug("solve_pnp: the initial guess explains too few points; running RANSAC")

    ok, rvec, tvec, idx = cv2.solvePnPRansac(
        X, x, K, d, iterationsCount=max_iters, reprojectionError=float(threshold_px),
        confidence=confidence, flags=getattr(cv2, _FLAGS[method]),
    )
    if not ok or idx is None or len(idx) < 4:
        raise GeometryError(f"solve_pnp: RANSAC found no pose consistent with >= 4 of {n} correspondences")
    T, mask = _refine_lm(_to_T(rvec, tvec), K, X, x, d, threshold_px)
    if mask.sum() < need:
        raise GeometryError(
            f"solve_pnp: only {int(mask.sum())} of {n} correspondences are inliers (< {need}) "
            f"at {threshold_px} px"
        )
    return T, mask


def reprojection_errors(
    T_cam_world: np.ndarray, K: np.ndarray, X_world: np.ndarray, x: np.ndarray, dist: np.ndarray | None = None
) -> np.ndarray:
    """Euclidean reprojection error per point, pixels (``inf`` for points behind the camera)."""
    uv, z = project_points(T_cam_world, K, X_world, dist)
    err = np.linalg.norm(uv - np.asarray(x, float), axis=1)
    return np.where(z > 0, err, np.inf)
