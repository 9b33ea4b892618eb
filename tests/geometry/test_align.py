"""3D-3D alignment (Umeyama inside RANSAC), cross-checked against evo."""
from __future__ import annotations

import numpy as np
import pytest

from vslam.errors import GeometryError
from vslam.geometry import align_points, make_T, rotation_error_deg, sim3_decompose, so3_exp, umeyama


def _scene(seed, n=300, noise=0.0, outlier_frac=0.0, scale=1.0):
    rng = np.random.default_rng(seed)
    src = rng.uniform([-4, -3, 4], [4, 3, 12], (n, 3))
    R = so3_exp(rng.normal(size=3))
    t = rng.normal(size=3) * 3
    dst = scale * src @ R.T + t + rng.normal(scale=noise, size=(n, 3)) if noise else scale * src @ R.T + t
    out = np.zeros(n, dtype=bool)
    k = int(outlier_frac * n)
    out[:k] = True
    dst[:k] = rng.uniform(-10, 10, (k, 3))
    return src, dst, R, t, out


@pytest.mark.parametrize("with_scale", [False, True])
def test_umeyama_agrees_with_evo(with_scale):
    from evo.core.geometry import umeyama_alignment

    src, dst, *_ = _scene(30, n=50, noise=0.05, scale=1.3 if with_scale else 1.0)
    R, t, s = umeyama(src, dst, with_scale)
    R_e, t_e, s_e = umeyama_alignment(src.T, dst.T, with_scale)
    np.testing.assert_allclose(R, R_e, atol=1e-10)
    np.testing.assert_allclose(t, t_e, atol=1e-10)
    assert abs(s - s_e) < 1e-10


@pytest.mark.parametrize("with_scale", [False, True])
def test_align_noise_free(with_scale):
    src, dst, R, t, _ = _scene(31, scale=0.7 if with_scale else 1.0)
    T, mask = align_points(src, dst, with_scale=with_scale, threshold=1e-6)
    assert mask.all()
    np.testing.assert_allclose(T, make_T(R, t, 0.7 if with_scale else 1.0), atol=1e-9)


@pytest.mark.parametrize("threshold", [0.15, None])
@pytest.mark.parametrize("seed", [32, 33])
def test_align_noise_and_outliers(seed, threshold):
    src, dst, R, t, out = _scene(seed, noise=0.03, outlier_frac=0.3, scale=1.7)
    T, mask = align_points(src, dst, with_scale=True, threshold=threshold)
    s, R_est, _ = sim3_decompose(T)
    assert rotation_error_deg(R_est, R) < 0.3
    assert abs(s / 1.7 - 1) < 0.01
    assert not (mask & out).any()
    assert mask[~out].mean() > 0.9


def test_align_degenerate_raises():
    src, dst, *_ = _scene(34, n=10)
    with pytest.raises(GeometryError, match="at least 3"):
        align_points(src[:2], dst[:2])
    line = np.c_[np.linspace(0, 1, 10), np.zeros((10, 2))]
    with pytest.raises(GeometryError, match="collinear"):
        align_points(line, line + 1.0, threshold=0.1)
    bad = dst.copy()
    bad[0, 0] = np.nan
    with pytest.raises(GeometryError, match="NaN"):
        align_points(src, bad)
    with pytest.raises(GeometryError, match="equal shape"):
        align_points(src, dst[:5])


def _planar_points(seed: int, n: int = 40) -> np.ndarray:
    """Points on the plane z = 0 (a ground-vehicle or table-top trajectory): the cross-covariance
    has rank 2, so the sign of its third singular direction is arbitrary and only the reflection
    guard ``S = diag(1, 1, det(U V^T))`` keeps ``R`` a rotation."""
    rng = np.random.default_rng(seed)
    return np.c_[rng.uniform(-5, 5, (n, 2)), np.zeros(n)]


@pytest.mark.parametrize("with_scale", [False, True])
def test_umeyama_never_returns_a_reflection_for_coplanar_points(with_scale):
    # unguarded, about half of these come out mirrored (det R = -1) with the same residual
    for seed in range(16):
        src = _planar_points(seed)
        R_true = so3_exp(np.random.default_rng(100 + seed).normal(size=3))
        t_true = np.array([1.0, -2.0, 0.5])
        s_true = 1.4 if with_scale else 1.0
        dst = s_true * src @ R_true.T + t_true
        R, t, s = umeyama(src, dst, with_scale)
        assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-9), seed
        np.testing.assert_allclose(R, R_true, atol=1e-9)
        np.testing.assert_allclose(t, t_true, atol=1e-9)
        assert s == pytest.approx(s_true, rel=1e-9)
        # evo (which has the guard) agrees on the planar case too
        from evo.core.geometry import umeyama_alignment

        R_e, t_e, s_e = umeyama_alignment(src.T, dst.T, with_scale)
        np.testing.assert_allclose(R, R_e, atol=1e-9)


def test_umeyama_batch_never_returns_a_reflection_for_coplanar_points():
    from vslam.geometry import umeyama_batch

    src = np.stack([_planar_points(s, n=3) for s in range(32)])
    R_true = so3_exp(np.random.default_rng(7).normal(size=(32, 3)))
    dst = np.einsum("mij,mkj->mki", R_true, src)
    R, _, _, valid = umeyama_batch(src, dst)
    assert valid.all()
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-9)
    np.testing.assert_allclose(R, R_true, atol=1e-8)
