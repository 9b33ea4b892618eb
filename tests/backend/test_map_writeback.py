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
