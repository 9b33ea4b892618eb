"""refine_pose with the compiled per-point kernels equals its NumPy reference bit for bit."""
from __future__ import annotations

import numpy as np
import pytest

from vslam.geometry import pnp, pnp_kernels
from vslam.geometry.lie import se3_exp
from vslam.geometry.pnp import refine_pose

K = np.array([[500.0, 0, 320], [0, 520.0, 240], [0, 0, 1]])


def test_warm_runs():
    pnp_kernels.warm()


def _problem(rng, n, stereo):
    X = rng.uniform([-2, -2, -0.5], [2, 2, 6], (n, 3))  # a few points behind the camera
    T = se3_exp(rng.normal(0, 0.1, 6))
    Xc = X @ T[:3, :3].T + T[:3, 3]
    uv = np.stack([500 * Xc[:, 0] / Xc[:, 2] + 320, 520 * Xc[:, 1] / Xc[:, 2] + 240], 1)
    uv += rng.normal(0, 0.7, uv.shape)
    uv[: n // 8] += rng.uniform(-40, 40, (n // 8, 2))  # outliers
    sigma = rng.uniform(1.0, 2.0, n)
    ur = None
    if stereo:
        ur = (uv[:, 0] - 40.0 / Xc[:, 2]).astype(np.float32)  # float32 as observations keep it
        ur[rng.random(n) < 0.3] = np.nan  # no depth
    T0 = se3_exp(rng.normal(0, 0.03, 6)) @ T
    return T0, X, uv, sigma, ur


@pytest.mark.parametrize("stereo", [False, True])
def test_refine_pose_kernels_equal_numpy(monkeypatch, stereo):
    rng = np.random.default_rng(11 + stereo)
    for n in (6, 40, 700):
        for _ in range(5):
            T0, X, uv, sigma, ur = _problem(rng, n, stereo)
            got = refine_pose(T0, X, uv, K, sigma, ur, 40.0, rounds=3)
            monkeypatch.setattr(pnp, "USE_KERNELS", False)
            want = refine_pose(T0, X, uv, K, sigma, ur, 40.0, rounds=3)
            monkeypatch.setattr(pnp, "USE_KERNELS", True)
            np.testing.assert_array_equal(got[0], want[0])
            np.testing.assert_array_equal(got[1], want[1])
            assert not np.array_equal(got[0], T0)


def test_linearize_and_inliers_equal_numpy_with_nan_and_behind(monkeypatch):
    rng = np.random.default_rng(5)
    T0, X, uv, sigma, ur = _problem(rng, 300, True)
    T0 = refine_pose(T0, X, uv, K, sigma, ur, 40.0)[0]  # most points inliers
    X[:5] = np.nan  # NaN propagates through np.maximum / np.where as in NumPy
    res = pnp._PoseResiduals.build(X, uv, K, sigma, ur, 40.0)
    inl = rng.random(300) < 0.9
    A1, r1, A2, r2 = np.empty((6, 900)), np.empty(900), np.empty((6, 900)), np.empty(900)
    res.linearize(T0, inl, A1, r1, True)
    in1 = res.inliers(T0)
    monkeypatch.setattr(pnp, "USE_KERNELS", False)
    res.linearize(T0, inl, A2, r2, True)
    in2 = res.inliers(T0)
    np.testing.assert_array_equal(A1, A2)
    np.testing.assert_array_equal(r1, r2)
    np.testing.assert_array_equal(in1, in2)
    assert 150 < in1.sum() < 300


def test_reproj_inliers_and_solve_pnp_equal_numpy(monkeypatch):
    rng = np.random.default_rng(9)
    for n in (30, 60, 500):
        T0, X, uv, _, _ = _problem(rng, n, False)
        X[0] = [0.0, 0.0, 0.0]  # at the camera centre of the identity: z = 0 under T = I
        got = [pnp._reproj_inliers(T0, K, X, uv, None, 3.0), pnp.solve_pnp(X, uv, K, None, T0, 3.0)]
        got.append(pnp.solve_pnp(X, uv, K, None, None, 3.0))
        monkeypatch.setattr(pnp, "USE_KERNELS", False)
        want = [pnp._reproj_inliers(T0, K, X, uv, None, 3.0), pnp.solve_pnp(X, uv, K, None, T0, 3.0)]
        want.append(pnp.solve_pnp(X, uv, K, None, None, 3.0))
        monkeypatch.setattr(pnp, "USE_KERNELS", True)
        for g, w in zip(got, want, strict=True):
            np.testing.assert_array_equal(g[0], w[0])
            np.testing.assert_array_equal(g[1], w[1])
        assert got[1][1].sum() > 0.6 * n
    eye = np.eye(4)
    got = pnp._reproj_inliers(eye, K, np.array([[0.0, 0, 0], [1, 1, -2], [np.nan, 0, 1]]), np.zeros((3, 2)), None, 9.0)
    monkeypatch.setattr(pnp, "USE_KERNELS", False)
    with np.errstate(all="ignore"):
        want = pnp._reproj_inliers(eye, K, np.array([[0.0, 0, 0], [1, 1, -2], [np.nan, 0, 1]]), np.zeros((3, 2)), None, 9.0)
    np.testing.assert_array_equal(got[0], want[0])
    np.testing.assert_array_equal(got[1], want[1])
