"""Triangulation, rejection helpers and rectified stereo."""
from __future__ import annotations

import cv2
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


@pytest.mark.parametrize("noise_px", [0.0, 1.0])
def test_triangulate_agrees_with_opencv(two_view, noise_px):
    s = two_view(seed=41, noise_px=noise_px)
    X = triangulate(s.T_cam1_world, s.T_cam2_world, s.K, s.x1, s.x2)
    Xh = cv2.triangulatePoints(s.K @ s.T_cam1_world[:3], s.K @ s.T_cam2_world[:3], s.x1.T, s.x2.T)
    X_cv = (Xh[:3] / Xh[3]).T
    if noise_px == 0:
        assert np.abs(X - X_cv).max() < 1e-6
        return
    # OpenCV's homogeneous DLT in pixels and ours (inhomogeneous, normalized coordinates) differ
    # by mm under noise; both must be equally close to the truth
    err = np.linalg.norm(X - s.X_world, axis=1)
    err_cv = np.linalg.norm(X_cv - s.X_world, axis=1)
    assert np.median(np.linalg.norm(X - X_cv, axis=1)) < 0.01
    assert np.median(err) < 1.05 * np.median(err_cv)
    assert np.percentile(err, 90) < 1.05 * np.percentile(err_cv, 90)
    depth = np.linalg.norm(s.X_world - np.linalg.inv(s.T_cam1_world)[:3, 3], axis=1)
    assert np.median(err / depth) < 0.02


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
