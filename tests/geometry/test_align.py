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
