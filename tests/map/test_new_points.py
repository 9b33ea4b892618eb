"""New monocular points between keyframes (vslam.map.new_points): exact geometry, the parallax and
reprojection gates, KLT anchors, descriptor matching, the keyframe mapping step with the map's covisibility."""
from __future__ import annotations

import numpy as np

from vslam.map.keyframe import KeyFrame
from vslam.map.map import Map
from vslam.map.new_points import KeyframeMapping, NewPointsParams, triangulate_new_points, triangulate_pairs

K = np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])


def _scene(n: int = 60, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(-2, 2, n), rng.uniform(-1.5, 1.5, n), rng.uniform(4, 8, n)])


def _keyframe(kf_id: int, T_world_cam: np.ndarray, X: np.ndarray, descriptors: np.ndarray | None = None) -> KeyFrame:
    T_cw = np.linalg.inv(T_world_cam)
    Xc = X @ T_cw[:3, :3].T + T_cw[:3, 3]
    uv = Xc[:, :2] / Xc[:, 2:] * K[0, 0] + K[:2, 2]
    n = len(X)
    return KeyFrame(id=kf_id, frame_index=kf_id, timestamp=float(kf_id), T_world_cam=T_world_cam, uv=uv.copy(),
                    uv_undist=uv.copy(), descriptors=descriptors, octave=np.zeros(n, np.int32),
                    depth=np.full(n, np.nan), point_ids=np.full(n, -1, np.int64))


def _shifted(x: float) -> np.ndarray:
    T = np.eye(4)
    T[0, 3] = x
    return T


def test_pairs_are_triangulated_exactly_and_both_keyframes_observe_them():
    X = _scene()
    map_ = Map()
    kf1, kf2 = _keyframe(0, np.eye(4), X), _keyframe(1, _shifted(0.5), X)  # 3.6-7 deg of parallax
    idx = np.arange(len(X))
    n = triangulate_pairs(map_, kf1, idx, kf2, idx, NewPointsParams(K=K))
    assert n == len(X)
    np.testing.assert_allclose(map_.points.position[kf2.point_ids], X, atol=1e-9)
    np.testing.assert_array_equal(kf1.point_ids, kf2.point_ids)
    assert (map_.points.n_obs[kf2.point_ids] == 2).all() and (map_.points.first_kf[kf2.point_ids] == 1).all()


def test_low_parallax_and_bad_reprojection_are_refused():
    X = _scene()
    idx = np.arange(len(X))
    map_ = Map()
    # 5 cm baseline at 4-8 m: 0.36-0.72 deg < min_parallax_deg
    assert triangulate_pairs(map_, _keyframe(0, np.eye(4), X), idx, _keyframe(1, _shifted(0.05), X), idx,
                             NewPointsParams(K=K, min_parallax_deg=1.0)) == 0
    kf1, kf2 = _keyframe(0, np.eye(4), X), _keyframe(1, _shifted(0.5), X)
    kf2.uv_undist[:10, 1] += 8.0  # off the epipolar line by 8 px: 4 px each after triangulation > 2 sigma
    n = triangulate_pairs(map_, kf1, idx, kf2, idx, NewPointsParams(K=K, max_reproj_sigmas=2.0))
    assert n == len(X) - 10 and (kf2.point_ids[:10] == -1).all()


def test_klt_anchors_and_the_keyframe_mapping_step():
    X = _scene()
    map_ = Map()
    kf0 = _keyframe(0, np.eye(4), X)
    map_.add_keyframe(kf0)
    kf1 = _keyframe(1, _shifted(0.5), X)
    kf1.point_ids[:20] = -1
    kf1.extra.update(triangulate=True, anchor_kf=np.r_[np.full(40, 0), np.full(20, -1)],
                     anchor_idx=np.arange(len(X)))
    map_.add_keyframe(kf1)
    KeyframeMapping(map_, NewPointsParams(K=K)).on_keyframe(kf1)
    assert (kf1.point_ids[:40] >= 0).all() and (kf1.point_ids[40:] == -1).all()  # unanchored tracks: none
    assert map_.covisibility[1] == {0: 40} and map_.covisibility[0] == {1: 40}


def test_descriptor_matching_with_previous_keyframes():
    X = _scene(80)
    rng = np.random.default_rng(1)
    desc = rng.integers(0, 256, (len(X), 32), dtype=np.uint8)
    map_ = Map()
    kf0 = _keyframe(0, np.eye(4), X, desc)
    map_.add_keyframe(kf0)
    kf1 = _keyframe(1, _shifted(0.5), X, desc)
    map_.add_keyframe(kf1)
    n = triangulate_new_points(map_, kf1, NewPointsParams(K=K, max_descriptor_distance=64.0))
    assert n == len(X)
    np.testing.assert_allclose(map_.points.position[kf1.point_ids], X, atol=1e-9)
