"""Shared fixtures: a small synthetic RGB-D + stereo sequence and the distance to its true surfaces."""
from __future__ import annotations

import numpy as np
import pytest

from vslam.datasets.synthetic import SyntheticConfig, SyntheticSequence, default_scene


def distance_to_scene(points: np.ndarray) -> np.ndarray:
    """Euclidean distance of ``(N, 3)`` world points to the nearest face (rectangle) of the default scene."""
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    best = np.full(len(points), np.inf)
    for f in default_scene().faces:
        lo, hi = np.zeros(3), np.zeros(3)
        lo[f.axis] = hi[f.axis] = f.offset
        lo[f.u_axis], hi[f.u_axis] = f.u_range
        lo[f.v_axis], hi[f.v_axis] = f.v_range
        best = np.minimum(best, np.linalg.norm(points - np.clip(points, lo, hi), axis=1))
    return best


# quarter-resolution 320x240 frames keep TSDF fusion fast; 8 views spread round the loop
SMALL = SyntheticConfig(n_frames=48, width=320, height=240, fx=262.5, fy=262.5, cx=159.5, cy=119.5, baseline=0.1)


@pytest.fixture(scope="session")
def synthetic_frames():
    seq = SyntheticSequence(SMALL)
    return [seq[i] for i in range(0, SMALL.n_frames, 6)]


@pytest.fixture(scope="session")
def scene_distance():
    return distance_to_scene


@pytest.fixture(scope="session")
def small_config() -> SyntheticConfig:
    return SMALL
