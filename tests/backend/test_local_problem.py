"""The local BA problem builder (vslam.backend.local_problem): its sort-free index helpers against
the NumPy calls they replace."""
from __future__ import annotations

import numpy as np

from tests.map._builders import large_map
from vslam.backend.config import BackendConfig
from vslam.backend.local_problem import LocalProblemBuilder, unique_rows
from vslam.geometry.camera import PinholeCamera

CAM = PinholeCamera(535.4, 539.2, 320.1, 247.6, 640, 480)


def test_unique_rows_is_np_unique_with_inverse():
    rng = np.random.default_rng(0)
    rows = rng.integers(900, 1000, 5000)
    ids, inv = unique_rows(rows, 1200)
    ref_ids, ref_inv = np.unique(rows, return_inverse=True)
    assert np.array_equal(ids, ref_ids) and np.array_equal(inv, ref_inv) and inv.dtype == ref_inv.dtype
    assert len(ids) == 100 and np.array_equal(ids[inv], rows)


def test_gather_keeps_each_points_first_observation_per_keyframe():
    m = large_map(seed=5, n_keyframes=12, n_keypoints=400, n_points=2400, n_covisible=4)
    kf = m.keyframes[6]
    kf.point_ids[300:340] = kf.point_ids[10:50][::-1]  # the same points seen twice by this keyframe
    builder = LocalProblemBuilder(m, CAM, "rgbd", BackendConfig(), 1.2)
    n_rows = len(m.points)
    member = np.zeros(n_rows + 1, bool)
    member[m.local_point_ids([4, 5, 6])] = True
    cols = {k: np.concatenate(v) for k, v in builder._gather([4, 5, 6], member, n_rows).items()}
    for kid in [4, 5, 6]:
        pid, k = m.keyframes[kid].point_ids, m.keyframes[kid]
        idx, pt, mine = cols["idx"][cols["kf"] == kid], cols["pt"][cols["kf"] == kid], cols["kf"] == kid
        sel = np.flatnonzero(member[np.where(pid >= 0, pid, n_rows)])
        _, first = np.unique(pid[sel], return_index=True)
        assert np.array_equal(idx, sel[np.sort(first)]) and np.array_equal(pt, pid[idx])
        # the gathered keypoint columns are the keyframe's, row by row
        assert np.array_equal(cols["uv"][mine], k.uv_undist[idx])
        assert np.array_equal(cols["sig"][mine], 1.2 ** k.octave[idx].astype(float))
        dep = k.depth[idx]
        assert np.array_equal(cols["d"][mine], np.where(np.isfinite(dep) & (dep > 0), dep, np.nan), equal_nan=True)
    assert np.all(np.diff(cols["kf"]) >= 0)  # keyframe by keyframe, in the given order
    assert np.count_nonzero(cols["kf"] == 6) == np.count_nonzero(kf.point_ids >= 0) - 40


def test_row_norms_is_np_linalg_norm_to_the_last_bit():
    from vslam.backend.local_problem import row_norms

    rng = np.random.default_rng(2)
    a = rng.normal(size=(20000, 3)) * 10.0 ** rng.uniform(-6, 6, (20000, 1))
    assert np.array_equal(row_norms(a), np.linalg.norm(a, axis=1))
    assert np.array_equal(row_norms(a - a[::-1]), np.linalg.norm(a - a[::-1], axis=1))


def test_repeated_builds_reuse_the_scratch_and_give_the_same_problem():
    """The selection scratch is kept between builds (a new tag per keyframe, no refill): a second and
    a third build, after the store grew, give the same problem as the first."""
    m = large_map(seed=5, n_keyframes=12, n_keypoints=400, n_points=2400, n_covisible=4)
    builder = LocalProblemBuilder(m, CAM, "rgbd", BackendConfig(), 1.2)
    first, _ = builder.build([5, 6], [4], m.local_point_ids([5, 6]), 6)
    again, _ = builder.build([5, 6], [4], m.local_point_ids([5, 6]), 6)
    m.points.add(np.ones((3000, 3)), None, np.zeros(3), 0)  # the store grows
    third, _ = LocalProblemBuilder(m, CAM, "rgbd", BackendConfig(), 1.2).build([5, 6], [4], m.local_point_ids([5, 6]), 6)
    grown, _ = builder.build([5, 6], [4], m.local_point_ids([5, 6]), 6)
    for p in (again, third, grown):
        for name in ("kf_ids", "pt_ids", "obs_kf", "obs_pt", "obs_uv", "obs_sigma", "obs_depth"):
            assert np.array_equal(getattr(p, name), getattr(first, name), equal_nan=True), name
    assert first.num_observations > 500 and len(builder._stamp) >= len(m.points) + 1
