"""Two-view ray geometry: midpoint depths, the rotation-only fit and the motion parallax test."""
from __future__ import annotations

import numpy as np

from vslam.errors import GeometryError
from vslam.geometry.essential import (
    bearings,
    check_K,
    check_pairs,
    fundamental_from_essential,
    normalize_points,
    sampson_distance,
)
from vslam.geometry.lie import angle_between_deg


def two_view_depths(R: np.ndarray, t: np.ndarray, f1: np.ndarray, f2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Depths ``(z1, z2)`` along rays ``f1, f2`` minimising ``||z1 R f1 + t - z2 f2||`` (midpoint method).

    Vectorized 2x2 normal equations; ``z`` are ray lengths (equal to camera z for rays with z = 1).
    Near-parallel rays give huge (or inf) depths.
    """
    a = f1 @ np.asarray(R, float).T  # R f1
    b = f2
    t = np.asarray(t, float).reshape(3)
    aa = np.sum(a * a, axis=1)
    bb = np.sum(b * b, axis=1)
    ab = np.sum(a * b, axis=1)
    at = a @ t
    bt = b @ t
    det = aa * bb - ab * ab
    with np.errstate(divide="ignore", invalid="ignore"):
        z1 = (-at * bb + ab * bt) / det
        z2 = (aa * bt - ab * at) / det
    return z1, z2


def rotation_only_fit(f1: np.ndarray, f2: np.ndarray, iterations: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Best rotation ``f2 ~ R f1`` between unit rays (Kabsch, trimmed), and each pair's residual angle.

    A trimmed least-squares loop keeps the rays whose residual is below 3x the median before
    refitting. The residual angle is the rotation-compensated parallax (degrees).
    """
    keep = np.ones(len(f1), dtype=bool)
    R = np.eye(3)
    res = np.zeros(len(f1))
    for _ in range(iterations):
        H = f2[keep].T @ f1[keep]
        U, _, Vt = np.linalg.svd(H)
        D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt)) or 1.0])
        R = U @ D @ Vt
        res = angle_between_deg(f1 @ R.T, f2)
        med = np.median(res[keep])
        new = res <= max(3.0 * med, 1e-9)
        if new.sum() < 3 or np.array_equal(new, keep):
            break
        keep = new
    return R, np.asarray(res)


def motion_parallax(
    E: np.ndarray, x1: np.ndarray, x2: np.ndarray, K: np.ndarray, mask: np.ndarray | None = None
) -> tuple[float, float]:
    """``(parallax_px, noise_px)``: is there enough translation to see, compared to the noise?

    ``parallax_px`` is the median rotation-compensated parallax of the (inlier) correspondences:
    a rotation-only model ``f2 ~ R f1`` (the infinite homography ``K R K^-1``) is fitted by
    :func:`rotation_only_fit` and its residual angles are converted to pixels with the focal
    length. ``noise_px`` is the median Sampson distance of the same points under ``E``. Under a pure
    rotation both measure only noise (ratio 1.9-3.0 over 240 synthetic pure rotations, 0.5-2 px
    noise, 0-30 % outliers); with a visible translation the parallax is several times the noise.
    Compare with model selection between a homography and E (Torr's GRIC; ORB-SLAM's H/F score
    ratio, Mur-Artal et al. 2015, sec. IV).
    """
    x1, x2 = check_pairs(x1, x2, 5, "motion_parallax")
    K = check_K(K)
    m = np.ones(len(x1), dtype=bool) if mask is None else np.asarray(mask, dtype=bool).ravel()
    if m.sum() < 5:
        raise GeometryError(f"motion_parallax needs at least 5 inliers, got {int(m.sum())}")
    f1 = bearings(normalize_points(x1[m], K))
    f2 = bearings(normalize_points(x2[m], K))
    _, par_deg = rotation_only_fit(f1, f2)
    focal = 0.5 * (K[0, 0] + K[1, 1])
    parallax_px = float(np.median(np.radians(par_deg)) * focal)
    noise_px = float(np.median(sampson_distance(fundamental_from_essential(E, K), x1[m], x2[m])))
    return parallax_px, noise_px
