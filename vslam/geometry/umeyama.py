"""Closed-form least-squares alignment of two point sets (Umeyama 1991; Arun et al. 1987)."""
from __future__ import annotations

import numpy as np

from vslam.errors import GeometryError


def umeyama(src: np.ndarray, dst: np.ndarray, with_scale: bool = False) -> tuple[np.ndarray, np.ndarray, float]:
    """Find ``R, t, s`` minimising ``sum ||dst_i - (s R src_i + t)||^2``.

    Umeyama, "Least-squares estimation of transformation parameters between two point
    patterns", PAMI 1991, eqs. (38)-(42): with the cross-covariance ``Sigma = (1/n) sum
    (dst_i - mu_d)(src_i - mu_s)^T = U D V^T``, ``R = U S V^T`` where ``S = diag(1, .., det(U V^T))``,
    ``s = trace(D S) / sigma_src^2`` and ``t = mu_d - s R mu_s``.

    Args:
        src, dst: ``(N, 3)`` corresponding points, ``N >= 3`` and not collinear.
        with_scale: estimate ``s`` (Sim(3)); otherwise ``s = 1`` (SE(3)).

    Returns:
        ``(R (3, 3), t (3,), s)``.

    Raises:
        GeometryError: fewer than 3 points, non-finite input, or a degenerate (collinear) set.
    """
    src = np.asarray(src, dtype=float)
    dst = np.asarray(dst, dtype=float)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3:
        raise GeometryError(f"umeyama needs two (N, 3) arrays of equal shape, got {src.shape} and {dst.shape}")
    n = src.shape[0]
    if n < 3:
        raise GeometryError(f"umeyama needs at least 3 point pairs, got {n}")
    if not (np.all(np.isfinite(src)) and np.all(np.isfinite(dst))):
        raise GeometryError("umeyama got NaN or inf coordinates")
    mu_s = src.mean(axis=0)
    mu_d = dst.mean(axis=0)
    xs = src - mu_s
    xd = dst - mu_d
    sigma = xd.T @ xs / n
    U, D, Vt = np.linalg.svd(sigma)
    if D[1] < 1e-12 * max(D[0], 1e-300):
        raise GeometryError("umeyama: the points are collinear or coincident (rank < 2)")
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[2, 2] = -1.0
    R = U @ S @ Vt
    if with_scale:
        var_s = np.sum(xs * xs) / n
        s = float(np.trace(np.diag(D) @ S) / var_s)
    else:
        s = 1.0
    t = mu_d - s * R @ mu_s
    return R, t, s
