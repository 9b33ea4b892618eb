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
    cols = builder._gather([4, 5, 6], member, n_rows)
    for kid, idx, pt in zip([4, 5, 6], cols["idx"], cols["pt"]):
        pid = m.keyframes[kid].point_ids
        sel = np.flatnonzero(member[np.where(pid >= 0, pid, n_rows)])
        _, first = np.unique(pid[sel], return_index=True)
        assert np.array_equal(idx, sel[np.sort(first)]) and np.array_equal(pt, pid[idx])
    assert len(cols["idx"][2]) == np.count_nonzero(kf.point_ids >= 0) - 40


def test_row_norms_is_np_linalg_norm_to_the_last_bit():
    from vslam.backend.local_problem import row_norms

    rng = np.random.default_rng(2)
    a = rng.normal(size=(20000, 3)) * 10.0 ** rng.uniform(-6, 6, (20000, 1))
    assert np.array_equal(row_norms(a), np.linalg.norm(a, axis=1))
    assert np.array_equal(row_norms(a - a[::-1]), np.linalg.norm(a - a[::-1], axis=1))
