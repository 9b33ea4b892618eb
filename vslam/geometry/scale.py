"""Monocular relative scale between two consecutive two-view reconstructions.

The same physical points triangulated in pair ``(k-1, k)`` (``X_prev``) and in pair ``(k, k+1)``
(``X_curr``, each with a unit-norm baseline) differ by an unknown scale ``r``; distances between
point pairs are invariant to the (different) reference frames, so
``r = median_ij ||X_prev_i - X_prev_j|| / ||X_curr_i - X_curr_j||`` (Scaramuzza & Fraundorfer,
"Visual Odometry: Part I", IEEE RAM 2011, eq. 6, with a median instead of a mean for robustness).
Multiply the current translation by ``r`` to express it in the previous scale.

Failure contract: :func:`relative_scale` raises :class:`vslam.errors.GeometryError`.
"""
from __future__ import annotations

import numpy as np

from vslam.errors import GeometryError


def _sq_dist_matrix(X: np.ndarray) -> np.ndarray:
    """All squared pairwise distances via the Gram matrix of the centred points (BLAS, no (N, N, 3))."""
    Xc = X - X.mean(axis=0)
    sq = np.einsum("ij,ij->i", Xc, Xc)
    return np.maximum(sq[:, None] + sq[None, :] - 2.0 * (Xc @ Xc.T), 0.0)


def relative_scale(
    X_prev: np.ndarray, X_curr: np.ndarray, max_points: int = 300, min_dist: float = 1e-9,
    outlier_mads: float = 3.0, seed: int = 0,
) -> float:
    """Median ratio of pairwise distances ``||X_prev_i - X_prev_j|| / ||X_curr_i - X_curr_j||``.

    A bad point corrupts every pair it belongs to (30 % bad points spoil 51 % of the pairs, too
    many for a plain median), so the ratios are first screened per point: each point's median
    log-ratio over its pairs is compared with the median of those, and points more than
    ``outlier_mads`` scaled MADs away are dropped. The answer is the median over the pairs of the
    remaining points. All pairs of up to ``max_points`` points (a seeded random subset beyond) are
    used, as ``(M, M)`` arrays.

    Args:
        X_prev, X_curr: ``(N, 3)`` the same ``N >= 2`` points in the two reconstructions (any frames).
        max_points: points used (random, seeded subset when ``N`` is larger).
        min_dist: pairs closer than this (in either set) are skipped.
        outlier_mads: per-point rejection threshold, in robust standard deviations (1.4826 MAD).

    Returns:
        The scale ``r`` (> 0) such that ``X_prev ~ r X_curr`` up to a rigid motion.

    Raises:
        GeometryError: shape mismatch, fewer than 2 points, NaN/inf, or no pair of distinct points.

    Example:
        >>> relative_scale(np.eye(3), 0.5 * np.eye(3))
        2.0
    """
    A = np.asarray(X_prev, dtype=float)
    B = np.asarray(X_curr, dtype=float)
    if A.shape != B.shape or A.ndim != 2 or A.shape[1] != 3:
        raise GeometryError(f"relative_scale needs two (N, 3) arrays of equal shape, got {A.shape} and {B.shape}")
    n = A.shape[0]
    if n < 2:
        raise GeometryError(f"relative_scale needs at least 2 points, got {n}")
    if not (np.all(np.isfinite(A)) and np.all(np.isfinite(B))):
        raise GeometryError("relative_scale got NaN or inf coordinates; drop untriangulated points first")
    if n > max_points:
        idx = np.random.default_rng(seed).choice(n, max_points, replace=False)
        A, B = A[idx], B[idx]
        n = max_points
    da2 = _sq_dist_matrix(A)
    db2 = _sq_dist_matrix(B)
    # Gram-matrix round-off is ~1e-16 of the squared spread: treat anything below 1e-12 of it as 0
    tol_a = max(min_dist**2, 1e-12 * float(np.max(da2)))
    tol_b = max(min_dist**2, 1e-12 * float(np.max(db2)))
    valid = (da2 > tol_a) & (db2 > tol_b)
    if not np.any(valid):
        raise GeometryError("relative_scale: all points coincide; the scale is undetermined")
    with np.errstate(divide="ignore", invalid="ignore"):
        L = 0.5 * np.log(da2 / db2)
    L[~valid] = np.nan
    iu = np.triu_indices(n, k=1)
    if n >= 5:
        # per-row median of the valid entries: NaNs sort last, so take the middle of the first k
        k = valid.sum(axis=1)
        has = k > 0
        S = np.sort(L, axis=1)
        rows = np.arange(n)
        lo = S[rows, np.maximum((k - 1) // 2, 0)]
        hi = S[rows, np.maximum(k // 2, 0)]
        per_point = np.where(has, 0.5 * (lo + hi), np.nan)
        med = np.nanmedian(per_point)
        mad = 1.4826 * np.nanmedian(np.abs(per_point - med))
        keep = has & (np.abs(per_point - med) <= max(outlier_mads * mad, 1e-12))
        pair_ok = keep[iu[0]] & keep[iu[1]] & valid[iu]
        if pair_ok.any():
            return float(np.exp(np.median(L[iu][pair_ok])))
    return float(np.exp(np.median(L[iu][valid[iu]])))
