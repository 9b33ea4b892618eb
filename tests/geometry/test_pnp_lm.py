"""The compiled Levenberg-Marquardt of solve_pnp's refinement (pnp_kernels.lm_reprojection) against
cv2.solvePnPRefineLM, which it replaced on undistorted pixels: same minimum on synthetic problems."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from vslam.geometry import pnp, pnp_kernels
from vslam.geometry.lie import project_to_so3, se3_exp, so3_exp

K = np.array([[520.0, 0.0, 319.5], [0.0, 525.0, 239.5], [0.0, 0.0, 1.0]])
CRIT = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 20, 1e-10)


def _problem(rng, n, noise_px, depth=(1.0, 6.0), t_scale=0.5, K=K):
    """World points in front of a random camera, their (noisy) pixels and a perturbed pose."""
    T = se3_exp(np.r_[rng.normal(0, t_scale, 3), rng.normal(0, 0.3, 3)])
    Xc = np.c_[rng.uniform(-1, 1, (n, 2)) * 0.6, np.ones(n)] * rng.uniform(*depth, (n, 1))
    X = (Xc - T[:3, 3]) @ T[:3, :3]  # R^T (Xc - t)
    uv = Xc[:, :2] / Xc[:, 2:] @ K[:2, :2].T + K[:2, 2]
    uv += rng.normal(0, noise_px, uv.shape)
    T0 = se3_exp(np.r_[rng.normal(0, 0.02 * t_scale, 3), rng.normal(0, 0.01, 3)]) @ T
    return T, T0, X, uv


def _cv2_refine(T0, X, uv, K=K):
    rvec, tvec = cv2.solvePnPRefineLM(X, uv, K, None, cv2.Rodrigues(T0[:3, :3])[0], T0[:3, 3].reshape(3, 1).copy(),
                                      CRIT)
    return pnp._to_T(rvec, tvec)


def _cost(T, X, uv, K=K):
    H, g = np.empty((6, 6)), np.empty(6)
    return pnp_kernels.reproj_normal_equations(T, X, uv, K, H, g)


@pytest.mark.parametrize("n, noise_px", [(4, 0.0), (6, 0.5), (50, 1.0), (500, 1.0), (1500, 2.0)])
def test_lm_reaches_cv2_solvepnprefinelm_minimum(n, noise_px):
    rng = np.random.default_rng(100 + n)
    for _ in range(10):
        T, T0, X, uv = _problem(rng, n, noise_px)
        got = pnp_kernels.lm_reprojection(T0, X, uv, K, pnp.LM_MAX_ITERS, pnp.LM_EPS)
        want = _cv2_refine(T0, X, uv)
        np.testing.assert_allclose(got, want, rtol=0, atol=3e-9)  # OpenCV's stops at |g| ~ 1e-5 (n = 6)
        assert _cost(got, X, uv) <= _cost(want, X, uv) * (1 + 1e-12) + 1e-18
        if noise_px == 0.0:
            np.testing.assert_allclose(got, T, rtol=0, atol=1e-12)
        else:
            assert np.abs(got - T0).max() > 1e-4  # it moved


def test_lm_far_scene():
    """KITTI-like scale: translations of 100 m, depths to 80 m, a 2 m / 0.6 deg initial error."""
    rng = np.random.default_rng(7)
    for _ in range(10):
        T, T0, X, uv = _problem(rng, 300, 1.0, depth=(3.0, 80.0), t_scale=100.0)
        got = pnp_kernels.lm_reprojection(T0, X, uv, K, pnp.LM_MAX_ITERS, pnp.LM_EPS)
        want = _cv2_refine(T0, X, uv)
        np.testing.assert_allclose(got[:3, :3], want[:3, :3], rtol=0, atol=1e-9)
        np.testing.assert_allclose(got[:3, 3], want[:3, 3], rtol=0, atol=1e-9 * 100)


def test_lm_skewed_intrinsics_minimizes_the_skewed_error():
    """A skew ``K[0, 1]`` is part of the projection (as in project_points and the inlier test);
    OpenCV's projectPoints ignores it, so cv2.solvePnPRefineLM minimized another error."""
    Ks = K.copy()
    Ks[0, 1] = 2.5
    rng = np.random.default_rng(9)
    H, g = np.empty((6, 6)), np.empty(6)
    for _ in range(5):
        T, T0, X, uv = _problem(rng, 300, 1.0, K=Ks)
        got = pnp_kernels.lm_reprojection(T0, X, uv, Ks, pnp.LM_MAX_ITERS, pnp.LM_EPS)
        cost = pnp_kernels.reproj_normal_equations(got, X, uv, Ks, H, g)
        assert cost < 0.95 * _cost(_cv2_refine(T0, X, uv, Ks), X, uv, Ks)
        assert cost == pytest.approx(2 * 300 * 1.0 ** 2, rel=0.15)  # chi-square, 2n - 6 dof
        assert np.abs(np.linalg.solve(H, g)).max() < 1e-9  # no Gauss-Newton step left (round-off)


def test_refine_lm_matches_cv2_and_keeps_the_distortion_path():
    """_refine_lm (inlier re-selection around the LM) equals the OpenCV path's result; with
    distortion coefficients it still runs OpenCV's LM."""
    rng = np.random.default_rng(3)
    T, _, X, uv = _problem(rng, 400, 1.0)
    T0 = se3_exp(np.r_[rng.normal(0, 0.005, 3), rng.normal(0, 0.001, 3)]) @ T
    uv[:60] += rng.uniform(-30, 30, (60, 2))  # outliers
    got, m_got = pnp._refine_lm(T0, K, X, uv, None, 3.0)
    want, m_want = pnp._refine_lm(T0, K, X, uv, np.zeros(5), 3.0)  # zero distortion: OpenCV's LM
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(m_got, m_want)
    assert 330 < m_got.sum() < 345


def test_refine_lm_starts_from_the_nearest_rotation():
    """A pose whose rotation is off SO(3) (round-off grown through the tracker's products) comes
    back a rotation, as OpenCV's LM (Rodrigues' SVD) returned it."""
    rng = np.random.default_rng(4)
    T, _, X, uv = _problem(rng, 300, 1.0)
    T0 = se3_exp(np.r_[rng.normal(0, 0.005, 3), rng.normal(0, 0.001, 3)]) @ T
    T0[:3, :3] += rng.normal(0, 1e-4, (3, 3))
    got, m_got = pnp._refine_lm(T0, K, X, uv, None, 3.0, rounds=1)
    want, m_want = pnp._refine_lm(T0, K, X, uv, np.zeros(5), 3.0, rounds=1)
    np.testing.assert_allclose(got[:3, :3].T @ got[:3, :3], np.eye(3), rtol=0, atol=1e-14)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(m_got, m_want)


def test_lm_stops_and_guards():
    rng = np.random.default_rng(5)
    T, T0, X, uv = _problem(rng, 40, 0.0)
    np.testing.assert_allclose(pnp_kernels.lm_reprojection(T0, X, uv, K, 0, 1e-10), T0, rtol=0, atol=1e-15)  # no step
    one = pnp_kernels.lm_reprojection(T0, X, uv, K, 1, 1e-10)
    assert 0 < _cost(one, X, uv) < 1e-3 * _cost(T0, X, uv)  # one Gauss-Newton-like step from 1 cm, 0.6 deg
    # a huge tolerance: one step only, then stop
    np.testing.assert_array_equal(pnp_kernels.lm_reprojection(T0, X, uv, K, 20, 1e3), one)
    # no points: singular normal equations (zero pivot), no step
    np.testing.assert_allclose(pnp_kernels.lm_reprojection(T0, X[:0], uv[:0], K, 20, 1e-10), T0, rtol=0, atol=1e-15)
    # a point on the camera plane (z = 0): the error is NaN/inf from the start, no step is kept
    Xz = np.r_[X, [[0.0, 0.0, 0.0]]]
    Tz = np.eye(4)
    assert not np.isfinite(_cost(Tz, Xz, np.r_[uv, [[0.0, 0.0]]]))
    np.testing.assert_array_equal(pnp_kernels.lm_reprojection(Tz, Xz, np.r_[uv, [[0.0, 0.0]]], K, 20, 1e-10), Tz)


def test_normal_equations_are_the_jacobian_of_the_left_update():
    """H = J^T J, g = J^T r with J by central differences of T <- [so3_exp(phi), rho; 0, 1] T."""
    Ks = K.copy()
    Ks[0, 1] = 1.5
    rng = np.random.default_rng(8)
    T, T0, X, uv = _problem(rng, 30, 1.0, K=Ks)
    H, g = np.empty((6, 6)), np.empty(6)
    cost = pnp_kernels.reproj_normal_equations(T0, X, uv, Ks, H, g)

    def resid(xi):
        dT = np.eye(4)
        dT[:3, :3] = so3_exp(xi[3:])
        dT[:3, 3] = xi[:3]
        Xc = X @ (dT @ T0)[:3, :3].T + (dT @ T0)[:3, 3]
        return (Xc[:, :2] / Xc[:, 2:] @ Ks[:2, :2].T + Ks[:2, 2] - uv).ravel()

    r = resid(np.zeros(6))
    J = np.stack([(resid(h) - resid(-h)) / 2e-6 for h in np.eye(6) * 1e-6], axis=1)
    assert cost == pytest.approx(r @ r, rel=1e-12)
    np.testing.assert_allclose(g, J.T @ r, rtol=1e-5, atol=1e-6 * np.abs(g).max())
    np.testing.assert_allclose(H, J.T @ J, rtol=1e-5, atol=1e-7 * np.abs(H).max())
    np.testing.assert_array_equal(H, H.T)


def test_nearest_rotation_kernel_equals_lie():
    rng = np.random.default_rng(12)
    for scale in (0.0, 1e-12, 1e-4, 0.3):
        M = so3_exp(rng.normal(0, 1, 3)) + rng.normal(0, scale, (3, 3))
        for MM in (M, -M):  # -M: det < 0, the nearest rotation flips the last singular direction
            R = np.empty((3, 3))
            pnp_kernels.nearest_rotation(MM, R)
            np.testing.assert_allclose(R, project_to_so3(MM), rtol=0, atol=1e-14)
            assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-14)


@pytest.mark.parametrize("angle", [0.0, 1e-10, 1e-8 * 0.99, 1e-8 * 1.01, 1e-3, 0.5, 3.0])
def test_so3_exp_kernel_equals_lie(angle):
    w = np.array([0.3, -0.5, 0.8])
    w *= angle / np.linalg.norm(w)
    R = np.empty((3, 3))
    pnp_kernels.so3_exp(*w, R)
    np.testing.assert_allclose(R, so3_exp(w), rtol=0, atol=2e-16 * 4)
