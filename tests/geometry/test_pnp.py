"""PnP + RANSAC + LM against synthetic truth."""
from __future__ import annotations

import numpy as np
import pytest

from vslam.errors import GeometryError
from vslam.geometry import inv_T, rotation_error_deg, se3_exp, solve_pnp


def _errors(T, T_true):
    return rotation_error_deg(T, T_true), np.linalg.norm(inv_T(T)[:3, 3] - inv_T(T_true)[:3, 3])


@pytest.mark.parametrize("method", ["p3p", "sqpnp"])
def test_pnp_noise_free(two_view, method):
    s = two_view(seed=20)
    T, mask = solve_pnp(s.X_world, s.x2, s.K, method=method)
    assert mask.all()
    dr, dt = _errors(T, s.T_cam2_world)
    assert dr < 1e-6 and dt < 1e-6


@pytest.mark.parametrize("n", [4, 5, 6])
def test_pnp_minimal_point_counts(two_view, n):
    s = two_view(seed=27, n=n)
    T, mask = solve_pnp(s.X_world, s.x2, s.K)
    assert mask.all()
    dr, dt = _errors(T, s.T_cam2_world)
    assert dr < 1e-6 and dt < 1e-6


@pytest.mark.parametrize("seed", [21, 22, 23])
def test_pnp_noise_and_outliers(two_view, seed):
    s = two_view(seed=seed, n=300, noise_px=1.0, outlier_frac=0.3)
    T, mask = solve_pnp(s.X_world, s.x2, s.K)
    dr, dt = _errors(T, s.T_cam2_world)
    assert dr < 0.3
    assert dt < 0.01 * 8.0  # 1 % of the mean scene depth (4-12 m)
    assert not (mask & s.outlier).any()
    assert mask[~s.outlier].mean() > 0.8


def test_pnp_with_initial_guess(two_view):
    s = two_view(seed=24, n=300, noise_px=1.0, outlier_frac=0.3)
    guess = s.T_cam2_world @ se3_exp(np.array([0.05, -0.03, 0.08, 0.01, -0.01, 0.015]))
    T, mask = solve_pnp(s.X_world, s.x2, s.K, T_cam_world_init=guess)
    dr, dt = _errors(T, s.T_cam2_world)
    assert dr < 0.3 and dt < 0.08
    assert not (mask & s.outlier).any()
    # a wildly wrong guess falls back to RANSAC and still succeeds
    bad = s.T_cam2_world @ se3_exp(np.array([2.0, 0.0, 0.0, 0.5, 0.0, 0.0]))
    T, _ = solve_pnp(s.X_world, s.x2, s.K, T_cam_world_init=bad)
    dr, dt = _errors(T, s.T_cam2_world)
    assert dr < 0.3 and dt < 0.08


def test_pnp_with_distortion(two_view):
    import cv2

    s = two_view(seed=25, n=200)
    dist = np.array([-0.2, 0.05, 0.001, -0.001, 0.0])
    rvec = cv2.Rodrigues(s.T_cam2_world[:3, :3])[0]
    x, _ = cv2.projectPoints(s.X_world, rvec, s.T_cam2_world[:3, 3], s.K, dist)
    T, mask = solve_pnp(s.X_world, x.reshape(-1, 2), s.K, dist=dist)
    dr, dt = _errors(T, s.T_cam2_world)
    assert mask.all() and dr < 1e-6 and dt < 1e-6


def test_pnp_degenerate_inputs_raise(two_view):
    s = two_view(seed=26, n=40)
    with pytest.raises(GeometryError, match="at least 4"):
        solve_pnp(s.X_world[:3], s.x2[:3], s.K)
    bad = s.x2.copy()
    bad[0, 1] = np.inf
    with pytest.raises(GeometryError, match="NaN or inf"):
        solve_pnp(s.X_world, bad, s.K)
    line = np.c_[np.linspace(-1, 1, 10), np.zeros(10), np.full(10, 5.0)]
    with pytest.raises(GeometryError, match="collinear"):
        solve_pnp(line, np.random.default_rng(0).uniform(0, 400, (10, 2)), s.K)
    # pure noise: no pose explains enough points
    rng = np.random.default_rng(1)
    with pytest.raises(GeometryError):
        solve_pnp(s.X_world[:20], rng.uniform(0, 640, (20, 2)), s.K, min_inliers=8)
