"""Point-fusion bookkeeping (vslam.map.fusion): the remap applied to every keyframe."""
from __future__ import annotations

import numpy as np

from tests.map._builders import large_map
from vslam.map.fusion import apply_remap, new_remap


def test_apply_remap_follows_chains_and_keeps_minus_one():
    m = large_map(seed=4, n_keyframes=20, n_keypoints=200, n_points=2000, n_covisible=3)
    before = {k: kf.point_ids.copy() for k, kf in m.keyframes.items()}
    remap = new_remap(len(m.points))
    remap[[5, 6, 100]] = [6, 7, 3]  # chains 5 -> 6 -> 7 and one plain merge
    apply_remap(m.keyframes.values(), remap)
    final = np.arange(len(m.points))
    final[[5, 6, 100]] = [7, 7, 3]
    for k, kf in m.keyframes.items():
        old = before[k]
        assert kf.point_ids.dtype == np.int64 and kf.point_ids is not old
        assert np.array_equal(kf.point_ids, np.where(old >= 0, final[np.maximum(old, 0)], -1))
    assert (before[0] == -1).sum() > 50 and np.isin([5, 6, 100], np.concatenate(list(before.values()))).all()
