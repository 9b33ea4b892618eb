"""Triangulation, rejection helpers and rectified stereo."""
from __future__ import annotations

import numpy as np
import pytest

from vslam.errors import GeometryError
from vslam.geometry import (
    cheirality_mask,
    depth_to_disparity,
    disparity_to_depth,
    good_triangulation_mask,
    make_T,
    parallax_deg,
    project_stereo,
    reprojection_error,
    triangulate,
    triangulate_stereo,
)


def test_triangulate_noise_free(two_view):
    s = two_view(seed=40)
    X = triangulate(s.T_cam1_world, s.T_cam2_world, s.K, s.x1, s.x2)
    assert np.abs(X - s.X_world).max() < 1e-6
    assert reprojection_error(s.T_cam1_world, s.K, X, s.x1).max() < 1e-6


def _svd_dlt(P1: np.ndarray, P2: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> np.ndarray:
    """HZ eq. 12.1 written out: one 4x4 ``A`` per point, ``X`` = the right singular vector of the
    smallest singular value (an independent reference for the batched OpenCV solve)."""
    out = []
    for (u1, v1), (u2, v2) in zip(x1, x2):
        A = np.stack([u1 * P1[2] - P1[0], v1 * P1[2] - P1[1], u2 * P2[2] - P2[0], v2 * P2[2] - P2[1]])
        X = np.linalg.svd(A)[2][-1]
        out.append(X[:3] / X[3])
    return np.array(out)


@pytest.mark.parametrize("noise_px", [0.0, 1.0])
def test_triangulate_is_the_homogeneous_dlt(two_view, noise_px):
    s = two_view(seed=41, noise_px=noise_px)
    X = triangulate(s.T_cam1_world, s.T_cam2_world, s.K, s.x1, s.x2)
    X_ref = _svd_dlt(s.K @ s.T_cam1_world[:3], s.K @ s.T_cam2_world[:3], s.x1, s.x2)
    np.testing.assert_allclose(X, X_ref, rtol=1e-7, atol=1e-9)
    if noise_px == 0:
        return
    # 1 px of noise on this narrow baseline: ~1.5 % of the depth (measured median 1.50 %)
    depth = np.linalg.norm(s.X_world - np.linalg.inv(s.T_cam1_world)[:3, 3], axis=1)
    rel = np.linalg.norm(X - s.X_world, axis=1) / depth
    assert 0.01 < np.median(rel) < 0.02


def test_triangulate_second_intrinsics_and_parallel_rays(two_view):
    s = two_view(seed=45, n=30)
    K2 = s.K.copy()
    K2[0, 0] *= 1.3
    K2[1, 2] += 7.0
    Xc2 = s.X_world @ s.T_cam2_world[:3, :3].T + s.T_cam2_world[:3, 3]
    x2 = Xc2[:, :2] / Xc2[:, 2:] @ K2[:2, :2].T + K2[:2, 2]
    X = triangulate(s.T_cam1_world, s.T_cam2_world, s.K, s.x1, x2, K2=K2)
    assert np.abs(X - s.X_world).max() < 1e-6
    # two cameras at one place: no depth (an arbitrary point on each ray's line), zero parallax: rejected
    X0 = triangulate(s.T_cam1_world, s.T_cam1_world, s.K, s.x1, s.x1)
    assert not good_triangulation_mask(s.T_cam1_world, s.T_cam1_world, s.K, s.x1, s.x1, X0).any()
    assert triangulate(s.T_cam1_world, s.T_cam2_world, s.K, s.x1[:0], s.x2[:0]).shape == (0, 3)


def test_rejection_helpers(two_view):
    s = two_view(seed=42, noise_px=0.5, outlier_frac=0.2)
    X = triangulate(s.T_cam1_world, s.T_cam2_world, s.K, s.x1, s.x2)
    par = parallax_deg(s.T_cam1_world, s.T_cam2_world, s.X_world)
    assert par.min() > 0 and par.max() < 30
    good = good_triangulation_mask(s.T_cam1_world, s.T_cam2_world, s.K, s.x1, s.x2, X, min_parallax_deg=0.5)
    assert not (good & s.outlier).any()
    assert good[~s.outlier].mean() > 0.8
    # a point behind camera 1
    X_behind = np.linalg.inv(s.T_cam1_world)[:3] @ np.array([0.0, 0.0, -5.0, 1.0])
    assert not cheirality_mask(s.T_cam1_world, X_behind[None])[0]
    assert np.isinf(reprojection_error(s.T_cam1_world, s.K, X_behind[None], np.zeros((1, 2))))[0]
    # a point seen by two cameras at the same place has zero parallax
    T = make_T(np.eye(3), np.zeros(3))
    assert parallax_deg(T, T, np.array([[0.0, 0.0, 5.0]]))[0] == 0.0


def test_triangulate_bad_input_raises(two_view):
    s = two_view(seed=43, n=10)
    bad = s.x1.copy()
    bad[2] = np.nan
    with pytest.raises(GeometryError, match="NaN"):
        triangulate(s.T_cam1_world, s.T_cam2_world, s.K, bad, s.x2)
    with pytest.raises(GeometryError, match="equal shape"):
        triangulate(s.T_cam1_world, s.T_cam2_world, s.K, s.x1, s.x2[:5])


def test_rectified_stereo_roundtrip():
    K = np.array([[450.0, 0, 320], [0, 450.0, 240], [0, 0, 1]])
    rng = np.random.default_rng(44)
    X = np.c_[rng.uniform(-3, 3, (100, 2)), rng.uniform(1, 30, 100)]
    uvr = project_stereo(X, K, 0.12)
    np.testing.assert_allclose(uvr[:, 0] - uvr[:, 2], 450.0 * 0.12 / X[:, 2])
    np.testing.assert_allclose(triangulate_stereo(uvr[:, :2], uvr[:, 2], K, 0.12), X, atol=1e-9)
    d = depth_to_disparity(X[:, 2], 450.0, 0.12)
    np.testing.assert_allclose(disparity_to_depth(d, 450.0, 0.12), X[:, 2])
    assert np.isnan(disparity_to_depth(np.array([0.0, -1.0]), 450.0, 0.12)).all()
    # the same as general two-view triangulation with the right camera at +b along x
    X2 = triangulate(np.eye(4), make_T(np.eye(3), [-0.12, 0, 0]), K, uvr[:, :2], uvr[:, [2, 1]])
    np.testing.assert_allclose(X2, X, atol=1e-8)
    with pytest.raises(GeometryError, match="baseline"):
        triangulate_stereo(uvr[:, :2], uvr[:, 2], K, 0.0)
