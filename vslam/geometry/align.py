"""Robust 3D-3D alignment: closed-form Umeyama/Arun inside a vectorized RANSAC.

Hypotheses come from minimal 3-point samples solved all at once (batched SVD of the 3x3
cross-covariances, Umeyama 1991 eqs. 38-42 / Arun et al. 1987); each is scored against every
point in one array operation; the best is re-fitted on its inliers with
:func:`vslam.geometry.umeyama.umeyama`. RANSAC: Fischler & Bolles, CACM 1981; without a threshold
the hypotheses are ranked by their median residual instead (LMedS, Rousseeuw 1984) and the
inlier threshold is derived from that median.

:func:`align_points` is the one 3D-3D RANSAC: loop verification (one threshold, LMedS for map
merging) and the tracker's ``motion=3d3d`` (per-point thresholds growing with depth) use it.

Failure contract: :func:`align_points` raises :class:`vslam.errors.GeometryError` (fewer than
3 points, NaN/inf, all points collinear, no hypothesis with 3 inliers); it never returns ``None``.
"""
from __future__ import annotations

import numpy as np

from vslam.errors import GeometryError
from vslam.geometry.lie import make_T
from vslam.geometry.umeyama import umeyama


def umeyama_batch(
    src: np.ndarray, dst: np.ndarray, with_scale: bool = False
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Umeyama on ``M`` small point sets at once: ``(M, k, 3)`` -> ``R (M, 3, 3), t (M, 3), s (M,), valid (M,)``.

    ``valid`` is False for degenerate (collinear/coincident) sets; their ``R, t, s`` are garbage.
    """
    mu_s = src.mean(axis=1)
    mu_d = dst.mean(axis=1)
    xs = src - mu_s[:, None]
    xd = dst - mu_d[:, None]
    k = src.shape[1]
    sigma = np.einsum("mki,mkj->mij", xd, xs) / k
    U, D, Vt = np.linalg.svd(sigma)
    sgn = np.sign(np.linalg.det(U) * np.linalg.det(Vt))
    sgn[sgn == 0] = 1.0
    S = np.ones((len(src), 3))
    S[:, 2] = sgn
    R = (U * S[:, None, :]) @ Vt
    var_s = np.sum(xs * xs, axis=(1, 2)) / k
    valid = (D[:, 1] > 1e-9 * np.maximum(D[:, 0], 1e-300)) & (var_s > 1e-300)
    if with_scale:
        s = np.sum(D * S, axis=1) / np.where(valid, var_s, 1.0)
        valid &= s > 0
    else:
        s = np.ones(len(src))
    t = mu_d - s[:, None] * np.einsum("mij,mj->mi", R, mu_s)
    return R, t, s, valid


def _sq_residuals(R, t, s, src, dst):
    """``||dst - (s R src + t)||^2`` for ``M`` hypotheses: ``(M, N)``."""
    d = (src @ (s[:, None, None] * np.swapaxes(R, 1, 2))) + (t[:, None, :] - dst[None])
    return np.einsum("mni,mni->mn", d, d)


def align_points(
    src: np.ndarray, dst: np.ndarray, with_scale: bool = False, threshold: float | np.ndarray | None = None,
    confidence: float = 0.999, max_iters: int = 1000, batch: int = 64, seed: int | np.random.Generator = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """``T`` (4x4) with ``dst ~ s R src + t`` and the inlier mask, robust to outliers.

    Args:
        src, dst: ``(N, 3)`` corresponding points, ``N >= 3``, not all collinear.
        with_scale: estimate a similarity (scale folded into ``T[:3, :3] = s R``); else SE(3).
        threshold: inlier distance in ``dst`` units, one for all pairs or ``(N,)`` per pair (the
            tracker's depth-dependent noise). ``None``: LMedS ranking, then
            ``threshold = 2.5 * median residual`` of the best hypothesis (needs < 50 % outliers).
        confidence: RANSAC stops once ``1 - (1 - w^3)^k >= confidence`` for the inlier ratio ``w``.
        max_iters: cap on the number of 3-point hypotheses (LMedS draws 128). batch: hypotheses per vectorized step.
        seed: random generator seed (deterministic by default), or a generator to draw from.

    Returns:
        ``(T (4, 4), inlier_mask (N,) bool)``. With exactly 3 points no RANSAC is run.

    Raises:
        GeometryError: bad shapes, fewer than 3 pairs, NaN/inf, collinear points, no consensus.
    """
    src, dst = _check_align_inputs(src, dst, threshold)
    n = src.shape[0]
    if n == 3:
        R, t, s = umeyama(src, dst, with_scale)
        return make_T(R, t, s), np.ones(3, dtype=bool)

    rng = np.random.default_rng(seed)
    best_score = -np.inf
    best = None
    needed = max_iters
    done = 0
    lmeds = threshold is None
    min_iters = min(128, max_iters) if lmeds else 0  # 128 samples: P(all contaminated) < 4e-8 at 50 % outliers
    if lmeds:
        needed = min_iters
    while done < max_iters and (done < needed or done < min_iters):
        m = min(batch, max_iters - done)
        idx = np.stack([rng.choice(n, 3, replace=False) for _ in range(m)]) if n < 64 \
            else rng.integers(0, n, size=(m, 3))
        R, t, s, valid = umeyama_batch(src[idx], dst[idx], with_scale)
        valid &= (idx[:, 0] != idx[:, 1]) & (idx[:, 0] != idx[:, 2]) & (idx[:, 1] != idx[:, 2])
        done += m
        if not np.any(valid):
            continue
        R, t, s = R[valid], t[valid], s[valid]
        res2 = _sq_residuals(R, t, s, src, dst)
        if lmeds:
            score = -np.median(res2, axis=1)
        else:
            score = np.count_nonzero(res2 < threshold * threshold, axis=1).astype(float)
        i = int(np.argmax(score))
        if score[i] > best_score:
            best_score = float(score[i])
            best = (R[i], t[i], s[i], np.sqrt(res2[i]))
            if not lmeds:
                needed = _ransac_iterations(best_score / n, confidence, max_iters)
    if best is None:
        raise GeometryError("align_points: every 3-point sample is degenerate (points collinear or coincident)")
    return _refit_on_inliers(src, dst, best[3], threshold, with_scale)


def _check_align_inputs(src, dst, threshold: float | None) -> tuple[np.ndarray, np.ndarray]:
    """The point arrays as float ``(N, 3)``; raise :class:`GeometryError` on bad input."""
    src = np.asarray(src, dtype=float)
    dst = np.asarray(dst, dtype=float)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3:
        raise GeometryError(f"align_points needs two (N, 3) arrays of equal shape, got {src.shape} and {dst.shape}")
    n = src.shape[0]
    if n < 3:
        raise GeometryError(f"align_points needs at least 3 point pairs, got {n}")
    if not (np.all(np.isfinite(src)) and np.all(np.isfinite(dst))):
        raise GeometryError("align_points got NaN or inf coordinates; drop those pairs first")
    if threshold is not None:
        thr = np.asarray(threshold, dtype=float)
        if thr.ndim > 1 or (thr.ndim == 1 and len(thr) != n) or not (np.all(np.isfinite(thr)) and np.all(thr > 0)):
            raise GeometryError(f"align_points: threshold must be a positive number or {n} of them, got {threshold}")
    return src, dst


def _refit_on_inliers(
    src: np.ndarray, dst: np.ndarray, res: np.ndarray, threshold: float | None, with_scale: bool
) -> tuple[np.ndarray, np.ndarray]:
    """Umeyama re-fit on the inliers of the best hypothesis (residuals ``res``), up to 3 times
    while the inlier set changes; without a threshold it is 2.5x the median residual (LMedS)."""
    thr = threshold if threshold is not None else max(2.5 * float(np.median(res)), 1e-12)
    mask = res < thr
    if mask.sum() < 3:
        raise GeometryError(f"align_points: the best hypothesis has only {int(mask.sum())} inliers (< 3)")
    for _ in range(3):
        R, t, s = umeyama(src[mask], dst[mask], with_scale)
        res = np.linalg.norm(dst - (s * src @ R.T + t), axis=1)
        new = res < thr
        if new.sum() < 3 or np.array_equal(new, mask):
            break
        mask = new
    return make_T(R, t, s), mask


def _ransac_iterations(w: float, confidence: float, max_iters: int) -> int:
    """Samples RANSAC needs for inlier ratio ``w``: ``log(1 - confidence) / log(1 - w^3)``
    (Fischler & Bolles 1981), capped at ``max_iters``; ``w <= 0`` (no inlier yet) needs them all."""
    if w >= 1:
        return 1
    denom = np.log1p(-(w ** 3)) if w > 0 else 0.0
    if not denom < 0:
        return max_iters
    k = np.log(max(1.0 - confidence, 1e-300)) / denom
    return int(min(max_iters, np.ceil(k))) if np.isfinite(k) else max_iters
