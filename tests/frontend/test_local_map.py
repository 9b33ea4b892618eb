"""Projection of the local map and guided matching."""
from __future__ import annotations

import numpy as np

from vslam.frontend.local_map import descriptor_distance, guided_match, project_local_points
from vslam.geometry.camera import PinholeCamera
from vslam.map.mappoint import MapPointStore

CAM = PinholeCamera(500.0, 500.0, 320.0, 240.0, 640, 480)


def test_descriptor_distance_hamming_and_l2():
    a = np.zeros((1, 32), np.uint8)
    b = np.zeros((1, 32), np.uint8)
    b[0, :3] = [1, 3, 255]
    assert descriptor_distance(a, b, True)[0] == 11
    np.testing.assert_allclose(descriptor_distance(np.ones((2, 4)), np.zeros((2, 4)), False), [2.0, 2.0])


def test_project_local_points_frustum_distance_and_angle():
    store = MapPointStore()
    X = np.array([[0, 0, 5.0], [0, 0, -5.0], [100, 0, 5.0], [0, 0, 50.0], [0.1, 0, 5.0]])
    ids = store.add(X, None, np.zeros(3), 0, np.ones(5), 8.0)  # seen from the origin at distances d
    store.normal[4] = [1.0, 0, 0]  # seen edge-on from the origin: outside the 60 deg cone
    store.max_distance[3] = 40.0  # too far for its scale range
    T_cw = np.eye(4)
    T_cw[2, 3] = 1.0  # camera 1 m behind the origin: distances grow by 1 m
    vis, uv, z = project_local_points(store, ids, T_cw, CAM)
    assert list(vis) == [0]
    np.testing.assert_allclose(uv, [[320, 240]])
    np.testing.assert_allclose(z, [6.0])


def test_guided_match_picks_closest_descriptor_within_radius():
    rng = np.random.default_rng(0)
    kp_uv = rng.uniform(0, 640, (400, 2))
    kp_desc = rng.integers(0, 256, (400, 32), dtype=np.uint8)
    truth = rng.choice(400, 100, replace=False)
    proj = kp_uv[truth] + rng.normal(0, 2.0, (100, 2))
    map_desc = kp_desc[truth].copy()
    map_desc[:, 0] ^= 0b1011  # 3 bits off
    m, k, d = guided_match(proj, map_desc, kp_uv, kp_desc, radius=10.0, binary=True, max_distance=50)
    assert len(m) >= 98
    assert np.array_equal(k, truth[m]) and np.all(d == 3)
    # a keypoint is claimed by at most one map point
    assert len(np.unique(k)) == len(k)
    # nothing within the radius: no match
    m, k, d = guided_match(proj + 100.0, map_desc, kp_uv + 1e4, kp_desc, radius=5.0)
    assert len(m) == 0
