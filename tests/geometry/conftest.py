"""Synthetic scenes with exact ground truth for the geometry tests."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from vslam.geometry.lie import inv_T, make_T, so3_exp, transform_points

K_TEST = np.array([[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]])
WIDTH, HEIGHT = 640, 480


@dataclass
class TwoView:
    K: np.ndarray
    T_cam1_world: np.ndarray
    T_cam2_world: np.ndarray
    X_world: np.ndarray  # (N, 3)
    x1: np.ndarray  # observed pixels (noise + outliers)
    x2: np.ndarray
    x1_true: np.ndarray
    x2_true: np.ndarray
    outlier: np.ndarray  # (N,) bool

    @property
    def T_cam2_cam1(self) -> np.ndarray:
        return self.T_cam2_world @ inv_T(self.T_cam1_world)


def project(T_cam_world: np.ndarray, X_world: np.ndarray, K: np.ndarray = K_TEST) -> tuple[np.ndarray, np.ndarray]:
    Xc = transform_points(T_cam_world, X_world)
    return (Xc[:, :2] / Xc[:, 2:]) @ K[:2, :2].T + K[:2, 2], Xc[:, 2]


def random_pose(rng: np.random.Generator, rot_deg: float = 15.0, trans: float = 2.0) -> np.ndarray:
    w = rng.normal(size=3)
    w *= np.radians(rng.uniform(0.3, 1.0) * rot_deg) / np.linalg.norm(w)
    return make_T(so3_exp(w), rng.normal(size=3) * trans)


def make_two_view(
    seed: int = 0, n: int = 300, noise_px: float = 0.0, outlier_frac: float = 0.0,
    depth: tuple[float, float] = (4.0, 12.0), baseline: tuple[float, float] = (0.6, 1.2),
    rot_deg: float = 10.0, pure_rotation: bool = False,
) -> TwoView:
    """Points at ``depth`` in camera 1 seen by a camera 2 moved by ``baseline`` metres and up to ``rot_deg``."""
    rng = np.random.default_rng(seed)
    T_cam1_world = random_pose(rng)
    w = rng.normal(size=3)
    w *= np.radians(rng.uniform(0.3, 1.0) * rot_deg) / np.linalg.norm(w)
    d = rng.normal(size=3)
    d /= np.linalg.norm(d)
    b = 0.0 if pure_rotation else rng.uniform(*baseline)
    T_cam2_cam1 = make_T(so3_exp(w), b * d)
    T_cam2_world = T_cam2_cam1 @ T_cam1_world
    X_world = np.zeros((0, 3))
    while len(X_world) < n:
        m = 4 * n
        uv = rng.uniform([0, 0], [WIDTH, HEIGHT], (m, 2))
        z = rng.uniform(*depth, m)
        Xc1 = np.c_[(uv - K_TEST[:2, 2]) / K_TEST[0, 0] * z[:, None], z]
        Xw = transform_points(inv_T(T_cam1_world), Xc1)
        uv2, z2 = project(T_cam2_world, Xw)
        ok = (z2 > 0.5) & (uv2[:, 0] >= 0) & (uv2[:, 0] < WIDTH) & (uv2[:, 1] >= 0) & (uv2[:, 1] < HEIGHT)
        X_world = np.vstack([X_world, Xw[ok]])
    X_world = X_world[:n]
    x1t, _ = project(T_cam1_world, X_world)
    x2t, _ = project(T_cam2_world, X_world)
    x1 = x1t + rng.normal(scale=noise_px, size=x1t.shape) if noise_px else x1t.copy()
    x2 = x2t + rng.normal(scale=noise_px, size=x2t.shape) if noise_px else x2t.copy()
    outlier = np.zeros(n, dtype=bool)
    n_out = int(round(outlier_frac * n))
    if n_out:
        idx = rng.choice(n, n_out, replace=False)
        outlier[idx] = True
        x2[idx] = rng.uniform([0, 0], [WIDTH, HEIGHT], (n_out, 2))
        outlier &= np.linalg.norm(x2 - x2t, axis=1) > 10.0  # a random pixel may land near the truth
    return TwoView(K_TEST.copy(), T_cam1_world, T_cam2_world, X_world, x1, x2, x1t, x2t, outlier)


@pytest.fixture
def two_view():
    """Factory: ``two_view(seed=..., noise_px=..., outlier_frac=..., ...)`` -> :class:`TwoView`."""
    return make_two_view
