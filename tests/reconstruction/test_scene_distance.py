"""The test oracle itself: distance of points to the synthetic scene's faces."""
from __future__ import annotations

import numpy as np

from vslam.datasets.synthetic import default_scene, sample_surface_points


def test_points_on_faces_have_zero_distance(scene_distance):
    pts, _ = sample_surface_points(default_scene(), 500, np.random.default_rng(0))
    assert np.abs(scene_distance(pts)).max() < 1e-9


def test_known_distances(scene_distance):
    # room x-range is -3..3, the table top is z = 0.75 over |x| <= 0.5, |y| <= 0.3 (parcel over 0.05..0.35 x)
    pts = np.array([[-2.9, 0.0, 1.5], [-0.3, 0.0, 0.80], [0.0, -1.0, 2.9]])
    np.testing.assert_allclose(scene_distance(pts), [0.1, 0.05, 0.1], atol=1e-12)
