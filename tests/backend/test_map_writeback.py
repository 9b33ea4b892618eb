"""Write-back after local BA (vslam.backend.map_writeback): normals and distance ranges."""
from __future__ import annotations

import numpy as np

from tests.map._builders import large_map
from vslam.backend.config import BackendConfig
from vslam.backend.local_problem import LocalProblemBuilder
from vslam.backend.map_writeback import PointWriteback
from vslam.backend.problem import BAResult
from vslam.geometry.camera import PinholeCamera

CAM = PinholeCamera(535.4, 539.2, 320.1, 247.6, 640, 480)


def test_update_normals_is_the_mean_unit_ray_summed_in_observation_order():
    m = large_map(seed=6, n_keyframes=10, n_keypoints=300, n_points=1500, n_covisible=4)
    builder = LocalProblemBuilder(m, CAM, "rgbd", BackendConfig(), 1.2)
    problem, _ = builder.build([5, 6, 7], [4], m.local_point_ids([5, 6, 7]), 7)
    result = BAResult(problem.kf_ids, problem.T_world_cam, problem.pt_ids, problem.X_world,
                      np.ones(problem.num_observations, bool), 0.0, 0.0, 0.0, 0.0, 0, 0.0, 0.0, 0.0, "test")
    good = np.ones(problem.num_points, bool)
    good[::7] = False
    PointWriteback(m, CAM).update_normals(problem, result, good)
    # reference: np.add.at of the unit rays (the order of the sums fixes the last bits)
    pt_row, kf_row = problem.pt_index(problem.obs_pt), problem.kf_index(problem.obs_kf)
    ray = problem.X_world[pt_row] - problem.T_world_cam[kf_row, :3, 3]
    unit = ray / np.maximum(np.linalg.norm(ray, axis=1), 1e-12)[:, None]
    acc = np.zeros((problem.num_points, 3))
    np.add.at(acc, pt_row, unit)
    ids = problem.pt_ids[good]
    assert np.array_equal(m.points.normal[ids], acc[good] / np.linalg.norm(acc[good], axis=1)[:, None])
    assert np.bincount(pt_row).max() >= 3 and np.all(np.abs(np.linalg.norm(m.points.normal[ids], axis=1) - 1) < 1e-12)


def _update_normals_before(store, problem, result, good):
    """update_normals as it was before its compiled pass (NumPy): the reference of the test below."""
    pt_row, kf_row = problem.pt_index(problem.obs_pt), problem.kf_index(problem.obs_kf)
    ray = result.X_world[pt_row] - result.T_world_cam[kf_row, :3, 3]
    dist = np.sqrt(ray[:, 0] * ray[:, 0] + ray[:, 1] * ray[:, 1] + ray[:, 2] * ray[:, 2])
    unit = ray / np.maximum(dist, 1e-12)[:, None]
    acc = np.stack([np.bincount(pt_row, weights=unit[:, c], minlength=problem.num_points) for c in range(3)], 1)
    norm = np.sqrt(acc[:, 0] * acc[:, 0] + acc[:, 1] * acc[:, 1] + acc[:, 2] * acc[:, 2])
    ok = good & (norm > 1e-9)
    store.normal[problem.pt_ids[ok]] = acc[ok] / norm[ok, None]
    last = np.full(problem.num_points, -1, np.int64)
    last[pt_row] = np.arange(len(pt_row))
    has = ok & (last >= 0)
    o, ids = last[has], problem.pt_ids[has]
    old_max, old_min = store.max_distance[ids], store.min_distance[ids]
    ratio = np.where((old_min > 0) & np.isfinite(old_max), old_max / np.maximum(old_min, 1e-12), 1.0)
    new_max = dist[o] * problem.obs_sigma[o]
    store.max_distance[ids] = new_max
    store.min_distance[ids] = new_max / np.maximum(ratio, 1.0)


def test_update_normals_equals_the_numpy_code_it_replaced_to_the_bit():
    """The compiled pass (normals and distance ranges) against the NumPy expressions it replaced,
    with moved points, points left out (``good``) and old ranges that are unset, inf or tiny."""
    import copy

    m = large_map(seed=8, n_keyframes=10, n_keypoints=300, n_points=1500, n_covisible=4)
    builder = LocalProblemBuilder(m, CAM, "rgbd", BackendConfig(), 1.2)
    problem, _ = builder.build([5, 6, 7], [4], m.local_point_ids([5, 6, 7]), 7)
    rng = np.random.default_rng(1)
    ids = problem.pt_ids
    m.points.min_distance[ids] = rng.uniform(0.1, 1.0, len(ids))
    m.points.max_distance[ids] = m.points.min_distance[ids] * rng.uniform(1.0, 8.0, len(ids))
    m.points.min_distance[ids[::5]] = 0.0
    m.points.max_distance[ids[1::5]] = np.inf
    m.points.min_distance[ids[2::5]] = 1e-14
    X = problem.X_world + rng.normal(scale=0.01, size=problem.X_world.shape)
    result = BAResult(problem.kf_ids, problem.T_world_cam, problem.pt_ids, X,
                      np.ones(problem.num_observations, bool), 0.0, 0.0, 0.0, 0.0, 0, 0.0, 0.0, 0.0, "test")
    good = np.ones(problem.num_points, bool)
    good[::7] = False
    ref = copy.deepcopy(m.points)
    PointWriteback(m, CAM).update_normals(problem, result, good)
    _update_normals_before(ref, problem, result, good)
    for name in ("normal", "max_distance", "min_distance"):
        assert np.array_equal(getattr(m.points, name), getattr(ref, name)), name
    assert np.isinf(m.points.max_distance[ids]).sum() == np.count_nonzero(~good & np.isinf(m.points.max_distance[ids]))
    assert len(np.unique(np.round(m.points.max_distance[ids] / np.maximum(m.points.min_distance[ids], 1e-300), 6))) > 100
