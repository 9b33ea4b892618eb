"""The compiled kernels of ``apply_remap`` and ``Map.update_covisibility`` against the NumPy
expressions they replace."""
from __future__ import annotations

import numpy as np

from vslam.map import fusion_kernels, map_kernels
from vslam.map.fusion import apply_remap, new_remap


class _KF:
    def __init__(self, point_ids):
        self.point_ids = point_ids


def _remap_reference(remap, keyframes, rounds):
    moved = np.flatnonzero(remap[:-1] != np.arange(len(remap) - 1))
    for _ in range(rounds):
        remap[moved] = remap[remap[moved]]
    return [remap[k.point_ids] for k in keyframes]


def test_apply_remap_kernels_are_the_numpy_remap():
    fusion_kernels.warm()
    rng = np.random.default_rng(5)
    n = 3000
    for rounds in (1, 4):
        remap = new_remap(n)
        loser = rng.choice(n, 400, replace=False)
        remap[loser] = rng.integers(0, n, 400)  # chains a -> b -> c among them
        kfs = [_KF(np.where(rng.random(800) < 0.3, -1, rng.integers(0, n, 800))) for _ in range(12)]
        ref_remap = remap.copy()
        want = _remap_reference(ref_remap, kfs, rounds)
        before = [k.point_ids for k in kfs]
        apply_remap(kfs, remap, chain_rounds=rounds)
        assert np.array_equal(remap, ref_remap)
        for k, w, b in zip(kfs, want, before):
            assert k.point_ids.dtype == np.int64 and np.array_equal(k.point_ids, w)
            assert k.point_ids is not b  # a new array, as the gather gave
        assert sum(int((k.point_ids != b).sum()) for k, b in zip(kfs, before)) > 500
        assert (remap[:-1] != np.arange(n)).sum() > 300 and remap[-1] == -1


def test_count_flagged_is_count_nonzero_of_the_gather():
    map_kernels.warm()
    rng = np.random.default_rng(8)
    flags = rng.random(2001) < 0.2
    flags[-1] = False  # the "no point" entry, as update_covisibility builds it
    for _ in range(5):
        pid = np.where(rng.random(1000) < 0.3, -1, rng.integers(0, 2000, 1000))
        assert map_kernels.count_flagged(flags, pid) == np.count_nonzero(flags[pid]) > 100
    flags[-1] = True  # negative ids index from the end, as in NumPy
    assert map_kernels.count_flagged(flags, np.array([-1, -1, 3], np.int64)) == np.count_nonzero(flags[[-1, -1, 3]])
