"""The compiled kernel of the local BA problem builder against the NumPy expressions it replaces."""
from __future__ import annotations

import numpy as np

from vslam.backend.local_problem_kernels import member_keypoints, warm


def _reference(pid: np.ndarray, member: np.ndarray, n_rows: int) -> np.ndarray:
    sel = np.flatnonzero(member[np.where(pid >= 0, pid, n_rows)])
    _, first = np.unique(pid[sel], return_index=True)
    return sel[np.sort(first)]


def test_member_keypoints_matches_the_numpy_selection():
    warm()
    rng = np.random.default_rng(7)
    n_rows = 3000
    member = np.zeros(n_rows + 1, bool)
    member[rng.choice(n_rows, 1200, replace=False)] = True
    stamp = np.full(n_rows + 1, -1, np.int64)
    total_dups = 0
    for tag in range(6):
        pid = rng.integers(-1, n_rows, 2000)
        pid[rng.random(2000) < 0.3] = -1
        ref = _reference(pid, member, n_rows)
        got = member_keypoints(pid, member, stamp, tag)
        assert np.array_equal(got, ref) and got.dtype == np.int64
        total_dups += np.count_nonzero(member[np.where(pid >= 0, pid, n_rows)]) - len(ref)
    assert total_dups > 100  # the draws repeat points within a keyframe: the first keypoint wins
    # a tag already used marks every point taken: nothing left
    assert len(member_keypoints(pid, member, stamp, 5)) == 0 and len(member_keypoints(pid[:0], member, stamp, 6)) == 0


def test_unit_ray_sums_is_the_numpy_bincount_to_the_bit():
    from vslam.backend.local_problem import row_norms
    from vslam.backend.local_problem_kernels import unit_ray_sums

    rng = np.random.default_rng(9)
    X = rng.normal(scale=5.0, size=(300, 3))
    T = np.tile(np.eye(4), (6, 1, 1))
    T[:, :3, 3] = rng.normal(size=(6, 3))
    pt_row, kf_row = rng.integers(0, 300, 2000), rng.integers(0, 6, 2000)
    X[pt_row[0]] = T[kf_row[0], :3, 3]  # a zero ray: the floored length
    ray = X[pt_row] - T[kf_row, :3, 3]
    dist_ref = row_norms(ray)
    unit = ray / np.maximum(dist_ref, 1e-12)[:, None]
    acc_ref = np.stack([np.bincount(pt_row, weights=unit[:, c], minlength=300) for c in range(3)], axis=1)
    acc, dist = np.zeros((300, 3)), np.empty(2000)
    unit_ray_sums(X, T, pt_row, kf_row, acc, dist)
    np.testing.assert_array_equal(acc, acc_ref)
    np.testing.assert_array_equal(dist, dist_ref)
    assert dist[0] == 0.0
