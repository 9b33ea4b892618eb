"""The compiled matching kernels give exactly the NumPy/SciPy reference's results (``USE_KERNELS``)."""
from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy.spatial import cKDTree

from vslam.geometry.camera import PinholeCamera
from vslam.geometry.lie import make_T
from vslam.map import matching, matching_kernels
from vslam.map.matching import guided_match, project_local_points
from vslam.map.mappoint import MapPointStore

CAM = PinholeCamera(500.0, 500.0, 320.0, 240.0, 640, 480)


def _both(monkeypatch, f, *args):
    got = f(*args)
    monkeypatch.setattr(matching, "USE_KERNELS", False)
    want = f(*args)
    monkeypatch.setattr(matching, "USE_KERNELS", True)
    return got, want


def _assert_same(got, want):
    for g, w in zip(got, want, strict=True):
        assert g.dtype == w.dtype
        np.testing.assert_array_equal(g, w)


def test_warm_runs():
    matching_kernels.warm()


def test_knn_grid_equals_kdtree_and_flags_ties():
    rng = np.random.default_rng(0)
    kp = np.round(rng.uniform(0, 100, (400, 2)))  # integer pixels: many equal distances
    proj = np.round(rng.uniform(-5, 105, (500, 2)) * 2) / 2
    for radius, k in ((3.0, 8), (6.5, 2), (12.0, 1)):
        idx, fallback, ok = matching_kernels.knn_grid(proj, kp, radius, k)
        assert ok
        want = cKDTree(kp).query(proj, k=k, distance_upper_bound=radius)[1].reshape(len(proj), k)
        assert 0 < fallback.sum() < len(proj)  # ties exist, but most rows are decided by the grid
        np.testing.assert_array_equal(idx[~fallback], want[~fallback])
        assert (idx[~fallback] < len(kp)).sum() > 100


def test_knn_grid_radius_is_strict():
    kp = np.array([[3.0, 4.0], [1.0, 1.0]])
    idx, fallback, _ = matching_kernels.knn_grid(np.zeros((1, 2)), kp, 5.0, 2)  # (3, 4) at exactly 5
    assert list(idx[0]) == [1, 2] and not fallback[0]


def test_knn_grid_declines_non_finite_keypoints():
    """The grid leaves non-finite keypoints to the KD-tree, which rejects them as before."""
    kp = np.array([[1.0, 1.0], [np.nan, 2.0], [3.0, 3.0]])
    assert not matching_kernels.knn_grid(np.zeros((1, 2)), kp, 5.0, 2)[2]
    desc = np.arange(96, dtype=np.uint8).reshape(3, 32)
    with pytest.raises(ValueError, match="finite"):
        guided_match(np.array([[2.0, 2.0]]), desc[2:], kp, desc, 5.0, True, 64.0, 0.9)


@pytest.mark.parametrize("seed", range(6))
def test_guided_match_kernels_equal_reference(monkeypatch, seed):
    rng = np.random.default_rng(seed)
    for trial in range(40):
        n, p = int(rng.integers(1, 300)), int(rng.integers(1, 300))
        kp = rng.uniform(0, 640, (n, 2))
        if trial % 2:
            kp = np.round(kp)  # ties for the KD-tree fallback
            kp[rng.integers(0, n, n // 4)] = kp[rng.integers(0, n, n // 4)]  # duplicate keypoints
        proj = kp[rng.integers(0, n, p)] + rng.normal(0, 4, (p, 2))
        width = (32, 32, 5)[trial % 3]  # 5 bytes: padded to one 64-bit word
        kd = rng.integers(0, 256, (n, width), dtype=np.uint8)
        md = kd[rng.integers(0, n, p)] ^ (rng.random((p, width)) < 0.1).astype(np.uint8)
        free = rng.random(n) < 0.8 if trial % 2 else None
        radius = float(rng.choice([1.0, 4.5, 12.0, 30.0, 1000.0]))
        k = int(rng.choice([1, 2, 8]))
        max_d = (64.0, None, 2.5)[trial % 3]
        ratio = (0.9, 1.0, 0.75, 0.8)[trial % 4]
        got, want = _both(monkeypatch, guided_match, proj, md, kp, kd, radius, True, max_d, ratio, k, None, free)
        _assert_same(got, want)


def test_select_matches_ratio_in_float32_on_all_distance_pairs(monkeypatch):
    """Every (best, second) pair of 256-bit distances: the float32 ``ratio * second`` test."""
    best, second = np.meshgrid(np.arange(257), np.arange(257), indexing="ij")
    best, second = best.ravel(), second.ravel()
    keep = best <= second
    best, second = best[keep], second[keep]
    m = len(best)
    cnt = np.r_[best, second]
    kd = np.packbits((np.arange(256)[None] < cnt[:, None]).astype(np.uint8), axis=1)  # cnt bits set
    grid = 5.0 * np.stack([np.arange(m) % 200, np.arange(m) // 200], 1)
    kp = np.r_[grid, grid + [0.0, 1.0]]  # the second-best candidate 0.5 px further than the best
    proj = grid + [0.0, 0.25]
    md = np.zeros((m, 32), np.uint8)
    for ratio, max_d in ((0.9, 64.0), (0.8, 100.5), (0.75, None)):
        got, want = _both(monkeypatch, guided_match, proj, md, kp, kd, 2.0, True, max_d, ratio, 2)
        _assert_same(got, want)
        assert len(got[0]) > 1000


@pytest.mark.parametrize("check_distance", [True, False])
def test_project_rest_equals_numpy(monkeypatch, check_distance):
    rng = np.random.default_rng(7)
    store = MapPointStore()
    X = rng.normal(0, 2, (3000, 3)) + [0, 0, 4]
    ids = store.add(X, None, np.zeros(3), 0, rng.uniform(0.5, 2, 3000), 8.0)
    normal = store.normal[ids] + rng.normal(0, 0.7, (3000, 3))  # some seen from past 60 degrees
    store.normal[ids] = normal / np.linalg.norm(normal, axis=1)[:, None]
    for _ in range(20):
        T = make_T(cv2.Rodrigues(rng.normal(0, 0.3, 3))[0], rng.normal(0, 0.5, 3))
        sel = ids[rng.choice(3000, 2000, replace=False)]
        margin = float(rng.choice([0.0, 3.0]))
        got, want = _both(monkeypatch, project_local_points, store, sel, T, CAM, margin, 0.5, check_distance)
        _assert_same(got, want)
        assert 30 < len(got[0]) < 1900


def test_guided_match_asks_a_lazy_tree_only_for_distance_ties():
    """``kp_tree`` may be a callable (``KeyFrame.keypoint_tree``): called only when the grid search
    leaves rows to the KD-tree; the matches are the same as with the tree given."""
    rng = np.random.default_rng(4)
    kp = rng.uniform(0, 200, (300, 2))
    desc = rng.integers(0, 256, (300, 32), dtype=np.uint8)
    proj = kp[:150] + rng.normal(scale=1.0, size=(150, 2))
    calls = []

    def lazy():
        calls.append(1)
        return cKDTree(kp)

    got = guided_match(proj, desc[:150], kp, desc, 4.0, True, 64.0, 0.9, kp_tree=lazy)
    want = guided_match(proj, desc[:150], kp, desc, 4.0, True, 64.0, 0.9, kp_tree=cKDTree(kp))
    _assert_same(got, want)
    assert calls == [] and len(got[0]) > 100  # random float pixels: no ties, no tree
    tie = np.round(kp)  # integer pixels: equal distances, the KD-tree decides those rows
    got = guided_match(np.round(proj), desc[:150], tie, desc, 4.0, True, 64.0, 0.9, kp_tree=lambda: calls.append(1) or cKDTree(tie))
    want = guided_match(np.round(proj), desc[:150], tie, desc, 4.0, True, 64.0, 0.9, kp_tree=cKDTree(tie))
    _assert_same(got, want)
    assert len(calls) == 1
