"""Projection of the local map and guided matching."""
from __future__ import annotations

import numpy as np

from vslam.map.matching import descriptor_distance, guided_match, project_local_points
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


def _guided_match_reference(proj_uv, map_desc, kp_uv, kp_desc, radius, max_distance, ratio):
    """Plain per-map-point loop (test oracle only): all keypoints within ``radius`` (at most the 8
    nearest), best/second best by Hamming distance (ties: nearer candidate first, as the KD-tree
    returns them), then one map point per keypoint (the smallest distance, ties: lower map index)."""
    bits = np.unpackbits(kp_desc, axis=1)
    best = {}
    for i, p in enumerate(proj_uv):
        dpx = np.linalg.norm(kp_uv - p, axis=1)
        near = np.argsort(dpx, kind="stable")[:8]
        near = near[dpx[near] <= radius]
        if len(near) == 0:
            continue
        hd = (bits[near] != np.unpackbits(map_desc[i])).sum(1)
        o = np.argsort(hd, kind="stable")
        second = hd[o[1]] if len(o) > 1 else np.inf
        if hd[o[0]] <= max_distance and (ratio >= 1.0 or hd[o[0]] < ratio * second):
            k = int(near[o[0]])
            if k not in best or hd[o[0]] < best[k][1]:
                best[k] = (i, int(hd[o[0]]))
    ks = np.array(sorted(best), np.int64)
    return np.array([best[k][0] for k in ks], np.int64), ks, np.array([best[k][1] for k in ks], np.float32)


def test_guided_match_equals_plain_loop_with_ties():
    """The vectorized matcher (packed-key sorts, 64-bit popcounts) gives exactly the loop's answer,
    including distance ties (few-bit descriptors make many) and keypoints claimed twice."""
    rng = np.random.default_rng(3)
    kp_uv = rng.uniform(0, 200, (300, 2))
    kp_desc = (rng.random((300, 32)) < 0.02).astype(np.uint8) * 255  # few set bytes: many equal distances
    proj = kp_uv[rng.integers(0, 300, 250)] + rng.normal(0, 3.0, (250, 2))
    map_desc = kp_desc[rng.integers(0, 300, 250)]
    for ratio in (1.0, 0.9):
        got = guided_match(proj, map_desc, kp_uv, kp_desc, radius=8.0, binary=True, max_distance=64.0, ratio=ratio)
        want = _guided_match_reference(proj, map_desc, kp_uv, kp_desc, 8.0, 64.0, ratio)
        assert len(want[0]) > 50
        for g, w in zip(got, want):
            np.testing.assert_array_equal(g, w)


def test_descriptor_distance_equals_unpacked_bits():
    rng = np.random.default_rng(4)
    a = rng.integers(0, 256, (500, 32), dtype=np.uint8)
    b = rng.integers(0, 256, (500, 32), dtype=np.uint8)
    want = (np.unpackbits(a, axis=1) != np.unpackbits(b, axis=1)).sum(1)
    np.testing.assert_array_equal(descriptor_distance(a, b, True), want)
    pairwise = (np.unpackbits(a, axis=1)[:, None] != np.unpackbits(b[:3], axis=1)[None]).sum(-1)
    np.testing.assert_array_equal(descriptor_distance(a[:, None], b[None, :3], True), pairwise)  # broadcast path
