"""Shared fixtures: a small synthetic RGB-D + stereo sequence and the distance to its true surfaces."""
from __future__ import annotations

import numpy as np
import pytest

from vslam.datasets.synthetic import SyntheticConfig, SyntheticSequence, distance_to_scene


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
