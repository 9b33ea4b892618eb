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


def test_scatter_min_equals_minimum_at_to_the_bit():
    """The compiled per-point minimum of max_parallax_deg gives np.minimum.at's result, NaN included."""
    from vslam.backend.local_problem_kernels import scatter_min

    rng = np.random.default_rng(3)
    index = rng.integers(0, 500, 20000)
    values = rng.uniform(-1.0, 1.0, 20000)
    values[rng.random(20000) < 0.001] = np.nan
    ref, got = np.ones(600), np.ones(600)
    with np.errstate(invalid="ignore"):  # NaN inputs on purpose
        np.minimum.at(ref, index, values)
    scatter_min(got, index, values)
    assert np.isnan(ref).sum() > 5 and (ref < 0.9).sum() > 400
    assert np.array_equal(got, ref, equal_nan=True)


def test_max_parallax_deg_equals_the_minimum_at_expression():
    """max_parallax_deg (compiled per-point minimum) against its NumPy expression with np.minimum.at."""
    from vslam.backend.local_problem import max_parallax_deg, row_norms

    rng = np.random.default_rng(4)
    n_points, m = 300, 2000
    point = np.sort(rng.integers(0, n_points, m))
    rng.shuffle(point)
    centres, X = rng.normal(size=(m, 3)), rng.normal(size=(n_points, 3))[point] * 5.0
    ray = X - centres
    ray /= np.maximum(row_norms(ray), 1e-12)[:, None]
    first = np.full(n_points, -1, np.int64)
    first[point[::-1]] = np.arange(m)[::-1]
    cos = np.einsum("ij,ij->i", ray, ray[first[point]])
    min_cos = np.ones(n_points)
    np.minimum.at(min_cos, point, cos)
    ref = np.degrees(np.arccos(np.clip(min_cos, -1.0, 1.0)))
    got = max_parallax_deg(centres, X, point, n_points)
    assert np.array_equal(got, ref) and (ref > 10.0).sum() > 100


def test_gather_keyframe_equals_member_keypoints_and_the_gathers():
    """The fused selection + gather of one keyframe against member_keypoints and NumPy fancy indexing,
    appended at an offset, with and without depth."""
    from vslam.backend.local_problem_kernels import gather_keyframe

    rng = np.random.default_rng(9)
    n_rows, N = 800, 600
    member = rng.random(n_rows + 1) < 0.5
    pid = rng.integers(-1, n_rows, N)
    uv, octave, depth = rng.normal(size=(N, 2)), rng.integers(0, 8, N).astype(np.int32), rng.normal(size=N)
    for use_depth in (True, False):
        ref_sel = member_keypoints(pid, member, np.full(n_rows + 1, -1, np.int64), 0)
        out = (np.full(N + 5, -7, np.int64), np.full(N + 5, -7, np.int64), np.full((N + 5, 2), np.nan),
               np.full(N + 5, -7, np.int32), np.full(N + 5, np.nan))
        n = gather_keyframe(pid, member, np.full(n_rows + 1, -1, np.int64), 3, uv, octave, depth, use_depth, *out, 5)
        assert n == 5 + len(ref_sel) and len(ref_sel) > 150
        assert np.array_equal(out[0][5:n], pid[ref_sel]) and np.array_equal(out[1][5:n], ref_sel)
        assert np.array_equal(out[2][5:n], uv[ref_sel]) and np.array_equal(out[3][5:n], octave[ref_sel])
        assert np.array_equal(out[4][5:n], depth[ref_sel]) == use_depth
        assert np.all(out[0][:5] == -7)


def test_unit_rays_equal_the_numpy_gathers_and_normalization():
    """The fused gathers + normalization of the builder's parallax test against the NumPy expressions
    they replaced (``position[pt] - centre[kf]``, divided by ``max(row_norms, 1e-12)``), a zero ray included."""
    from vslam.backend.local_problem import row_norms
    from vslam.backend.local_problem_kernels import unit_rays

    rng = np.random.default_rng(6)
    position = rng.normal(size=(500, 3)) * 10.0 ** rng.uniform(-3, 3, (500, 1))
    centre = rng.normal(size=(40, 3))
    pt, kf = rng.integers(0, 500, 5000), rng.integers(0, 40, 5000)
    position[pt[0]] = centre[kf[0]]  # a zero ray: divided by the 1e-12 floor
    ref = position[pt] - centre[kf]
    ref /= np.maximum(row_norms(ref), 1e-12)[:, None]
    got = np.empty((5000, 3))
    unit_rays(position, pt, centre, kf, got)
    assert np.array_equal(got, ref) and np.all(got[0] == 0.0)
