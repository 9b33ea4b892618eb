"""Pyramid quotas and the grid spread of keypoints."""
from __future__ import annotations

import numpy as np

from vslam.features.pyramid import grid_select, level_quotas


def test_grid_select_round_robin():
    uv = np.array([[1, 1], [2, 2], [3, 3], [50, 50], [51, 51]], np.float32)
    score = np.array([5.0, 9.0, 1.0, 3.0, 2.0])
    # round 1: best of each cell (idx 1 then 3), round 2: second best (0 then 4)
    np.testing.assert_array_equal(grid_select(uv, score, 10, 4), [1, 3, 0, 4])


def test_level_quotas_sum():
    q = level_quotas(2000, 8, 1.2)
    assert q.sum() == 2000 and (np.diff(q) <= 0).all()
