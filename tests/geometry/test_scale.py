"""Monocular relative scale between consecutive reconstructions."""
from __future__ import annotations

import numpy as np
import pytest

from vslam.errors import GeometryError
from vslam.geometry import (
    camera_center,
    inv_T,
    make_T,
    project_points,
    relative_scale,
    so3_exp,
    transform_points,
    triangulate,
)


def _scaled(T_cam_world, s):
    """The same camera in a world scaled by ``s``."""
    T = T_cam_world.copy()
    T[:3, 3] *= s
    return T


def test_relative_scale_exact():
    rng = np.random.default_rng(50)
    X = rng.normal(size=(100, 3)) * 3
    T = make_T(so3_exp(rng.normal(size=3)), rng.normal(size=3))
    assert abs(relative_scale(X, 0.25 * transform_points(T, X)) - 4.0) < 1e-12
    big = rng.normal(size=(1000, 3))
    assert abs(relative_scale(big, big * 2.0, max_points=300) - 0.5) < 1e-12


@pytest.mark.parametrize("seed", [51, 52])
def test_relative_scale_from_two_noisy_monocular_pairs(seed):
    """Three cameras 0.6-1.2 m apart, points at 4-12 m, 1 px noise, 30 % bad triangulations."""
    rng = np.random.default_rng(seed)
    K = np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])
    n = 300
    X = np.c_[rng.uniform(-4, 4, n), rng.uniform(-3, 3, n), rng.uniform(4, 12, n)]
    Ts = [np.eye(4)]
    for _ in range(2):
        d = np.array([1.0, 0.0, 0.0]) + rng.normal(scale=0.2, size=3)
        C = camera_center(Ts[-1]) + rng.uniform(0.6, 1.2) * d / np.linalg.norm(d)
        R = so3_exp(rng.normal(scale=0.02, size=3))
        Ts.append(make_T(R, -R @ C))
    x = [project_points(T, K, X)[0] + rng.normal(size=(n, 2)) for T in Ts]
    b01 = np.linalg.norm(camera_center(Ts[1]) - camera_center(Ts[0]))
    b12 = np.linalg.norm(camera_center(Ts[2]) - camera_center(Ts[1]))
    # each pair reconstructed in its own unit-baseline frame, as monocular VO does
    X_prev = triangulate(_scaled(Ts[0], 1 / b01), _scaled(Ts[1], 1 / b01), K, x[0], x[1])
    X_curr = triangulate(_scaled(Ts[1], 1 / b12), _scaled(Ts[2], 1 / b12), K, x[1], x[2])
    X_curr = transform_points(inv_T(_scaled(Ts[1], 1 / b12)), X_curr)  # any frame will do
    bad = rng.choice(n, int(0.3 * n), replace=False)
    X_curr[bad] += rng.normal(scale=3.0, size=(len(bad), 3))
    r = relative_scale(X_prev, X_curr)
    assert abs(r / (b12 / b01) - 1) < 0.01


def test_relative_scale_bad_input_raises():
    with pytest.raises(GeometryError, match="at least 2"):
        relative_scale(np.zeros((1, 3)), np.zeros((1, 3)))
    with pytest.raises(GeometryError, match="coincide"):
        relative_scale(np.ones((5, 3)), np.ones((5, 3)))
    X = np.ones((5, 3))
    X[1, 2] = np.nan
    with pytest.raises(GeometryError, match="NaN"):
        relative_scale(X, X)
