"""Map structures: columnar point store, keyframes, covisibility, culling and compaction."""
from __future__ import annotations

import numpy as np

from vslam.map import KeyFrame, Map, MapPointStore


def _kf(kf_id: int, point_ids: np.ndarray, x: float = 0.0) -> KeyFrame:
    n = len(point_ids)
    T = np.eye(4)
    T[0, 3] = x
    return KeyFrame(kf_id, kf_id, float(kf_id), T, np.zeros((n, 2)), np.zeros((n, 2)),
                    np.zeros((n, 32), np.uint8), np.zeros(n, np.int32), np.full(n, np.nan), np.asarray(point_ids))


def test_store_add_grow_and_snapshot():
    store = MapPointStore(capacity=4)
    X = np.array([[0.0, 0.0, 2.0], [1.0, 0.0, 0.0], [0.0, 3.0, 4.0]])
    desc = np.arange(96, dtype=np.uint8).reshape(3, 32)
    ids = store.add(X, desc, np.zeros(3), keyframe_id=0, level_scale=np.array([1.0, 1.2, 1.44]), max_level_scale=1.2 ** 7)
    ids2 = store.add(X + 1, desc, np.zeros(3), keyframe_id=1)
    assert list(ids) == [0, 1, 2] and list(ids2) == [3, 4, 5] and len(store) == 6 and store.n_alive == 6
    mp = store.get(2)
    np.testing.assert_allclose(mp.position, [0, 3, 4])
    np.testing.assert_allclose(mp.normal, [0, 0.6, 0.8])
    assert np.isclose(mp.max_distance, 5.0 * 1.44) and np.isclose(mp.min_distance, 5.0 * 1.44 / 1.2 ** 7)
    assert np.array_equal(mp.descriptor, desc[2])
    store.record(np.array([0, 0, 1]), np.array([0]))
    assert store.visible[0] == 3 and store.found[0] == 2 and store.get(0).found_ratio == 2 / 3


def test_covisibility_weights_and_local_points():
    m = Map()
    store = m.points
    store.add(np.random.default_rng(0).normal(size=(10, 3)) + [0, 0, 5], None, np.zeros(3), 0)
    m.add_keyframe(_kf(0, np.array([0, 1, 2, 3, 4, -1])))
    m.add_keyframe(_kf(1, np.array([2, 3, 4, 5, 6, -1])))
    m.add_keyframe(_kf(2, np.array([6, 7, 8, 9])))
    assert m.covisibility[0] == {1: 3} and m.covisibility[1] == {0: 3, 2: 1}
    assert m.covisible(1) == [0, 2] and m.local_keyframes(1, 1) == [1, 0]
    assert list(m.local_point_ids([0, 1])) == [0, 1, 2, 3, 4, 5, 6]
    assert store.n_obs[2] == 2 and store.n_obs[0] == 1  # creation counts keyframe 0 once
    obs = m.point(3).observations
    assert obs == {0: 3, 1: 1}


def test_cull_and_compact_remaps_keyframes():
    m = Map()
    m.points.add(np.ones((6, 3)), np.zeros((6, 32), np.uint8), np.zeros(3), 0)
    m.add_keyframe(_kf(0, np.array([0, 1, 2, 3, 4, 5])))
    m.points.visible[:6] = 10
    m.points.found[:6] = [10, 1, 10, 1, 10, 10]
    assert m.cull_points(0.25) == 2 and m.n_points == 4
    m.compact()
    assert len(m.points) == 4
    assert list(m.keyframes[0].point_ids) == [0, -1, 1, -1, 2, 3]


def test_limit_points_keeps_local_window():
    m = Map()
    m.points.add(np.ones((4, 3)), None, np.zeros(3), 0)
    m.add_keyframe(_kf(0, np.array([0, 1])))
    m.points.add(np.ones((4, 3)), None, np.zeros(3), 1)
    m.add_keyframe(_kf(1, np.array([4, 5, 6, 7])))
    m.limit_points(5, keep_kf_ids=[1])
    assert m.n_points == 5
    kept = m.keyframes[1].point_ids
    assert np.all(kept >= 0)  # the local keyframe's points survive


def _update_covisibility_reference(m: Map, kf_id: int) -> None:
    """``Map.update_covisibility`` as the per-keyframe ``observed_ids`` / ``bincount`` version did it."""
    kf = m.keyframes[kf_id]
    mine = np.zeros(len(m.points), dtype=bool)
    mine[kf.observed_ids()] = True
    links = m.covisibility.setdefault(kf_id, {})
    others = [o for o in m.keyframes.values() if o.id != kf_id and o.segment == kf.segment and not o.bad]
    obs = [o.observed_ids() for o in others]
    owner = np.repeat(np.arange(len(others)), [len(a) for a in obs])
    weights = np.bincount(owner[mine[np.concatenate(obs)]], minlength=len(others))
    for j in np.flatnonzero(weights >= 1):
        links[others[j].id] = int(weights[j])
        m.covisibility.setdefault(others[j].id, {})[kf_id] = int(weights[j])


def test_update_covisibility_matches_the_reference_counts_and_order():
    import copy

    from tests.map._builders import large_map

    m = large_map(seed=3, n_keyframes=40, n_keypoints=300, n_points=6000, n_covisible=5)
    m.keyframes[7].bad = True
    m.keyframes[9].segment = 1
    m.keyframes[12].point_ids[:50] = -1
    m.covisibility = {k: {} for k in m.keyframes}
    ref = copy.deepcopy(m)
    for k in (0, 12, 25, 39, 12):
        m.update_covisibility(k)
        _update_covisibility_reference(ref, k)
    # same weights in the same insertion order (Map.covisible breaks ties by it)
    assert [(k, list(v.items())) for k, v in m.covisibility.items()] == \
        [(k, list(v.items())) for k, v in ref.covisibility.items()]
    assert len(m.covisibility[12]) > 20 and 7 not in m.covisibility[12] and 9 not in m.covisibility[12]
