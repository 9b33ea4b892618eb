"""Dense RGB-D alignments as local-BA constraints (vslam.backend.dense_links)."""
from __future__ import annotations

import dataclasses

import numpy as np
from scipy.spatial.transform import Rotation

from vslam.backend.bundle_adjustment import local_bundle_adjustment
from vslam.backend.config import LocalBAConfig
from vslam.backend.dense_links import add_dense_links, strip_dense_links
from vslam.map.dense_links import DenseLink, sample_depth_grid
from vslam.backend.problem import BAProblem
from vslam.geometry.camera import PinholeCamera

CAM = PinholeCamera(535.4, 539.2, 320.1, 247.6, 640, 480)


def _pose(rotvec, t) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
    T[:3, 3] = t
    return T


def _project(T_world_cam: np.ndarray, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    T = np.linalg.inv(T_world_cam)
    Xc = X @ T[:3, :3].T + T[:3, 3]
    return np.column_stack([CAM.fx * Xc[:, 0] / Xc[:, 2] + CAM.cx, CAM.fy * Xc[:, 1] / Xc[:, 2] + CAM.cy]), Xc[:, 2]


def _two_keyframes(n_points: int = 2, seed: int = 0):
    """Keyframe 0 fixed at the origin, keyframe 1 the true motion T_0_1 away but started 5 cm /
    2 deg off; ``n_points`` feature points seen by both (too few to fix keyframe 1 alone)."""
    rng = np.random.default_rng(seed)
    T_0_1 = _pose([0.02, 0.10, 0.01], [0.15, 0.02, 0.03])
    X = np.column_stack([rng.uniform(-0.5, 0.5, n_points), rng.uniform(-0.4, 0.4, n_points),
                         rng.uniform(1.5, 3.0, n_points)])
    uv0, z0 = _project(np.eye(4), X)
    uv1, z1 = _project(T_0_1, X)
    T1_start = T_0_1 @ _pose([0.03, 0.0, 0.02], [0.05, -0.03, 0.04])
    problem = BAProblem(
        camera=CAM, kf_ids=np.array([0, 1]), T_world_cam=np.stack([np.eye(4), T1_start]), pt_ids=np.arange(n_points),
        X_world=X + 0.01, obs_kf=np.repeat([0, 1], n_points), obs_pt=np.tile(np.arange(n_points), 2),
        obs_uv=np.concatenate([uv0, uv1]), obs_depth=np.concatenate([z0, z1]), fixed_kf_ids=np.array([0]),
    )
    uv = rng.uniform([0, 0], [640, 480], (40, 2))
    depth = rng.uniform(1.0, 3.0, 40)
    return problem, T_0_1, {1: DenseLink(1, 0, T_0_1, uv, depth)}


def _error(T: np.ndarray, T_true: np.ndarray) -> tuple[float, float]:
    d = np.linalg.inv(T_true) @ T
    return float(np.linalg.norm(d[:3, 3])), float(np.degrees(np.linalg.norm(Rotation.from_matrix(d[:3, :3]).as_rotvec())))


def test_a_link_pins_the_relative_pose_and_is_stripped_from_the_result():
    problem, T_0_1, links = _two_keyframes()
    linked, n = add_dense_links(problem, links)
    assert n == 40 and linked.num_points == problem.num_points + 40
    assert linked.num_observations == problem.num_observations + 80
    assert np.all(linked.pt_ids[problem.num_points:] < 0)
    result = local_bundle_adjustment(linked, LocalBAConfig())
    real, res = strip_dense_links(linked, result, n)
    assert real.num_points == problem.num_points and real.num_observations == problem.num_observations
    assert len(res.pt_ids) == problem.num_points and len(res.inlier_mask) == problem.num_observations
    np.testing.assert_array_equal(res.pt_ids, problem.pt_ids)
    dist, ang = _error(res.T_world_cam[1], T_0_1)
    assert dist < 1e-6 and ang < 1e-5, (dist, ang)


def test_without_the_link_two_points_leave_the_pose_off():
    problem, T_0_1, _ = _two_keyframes()
    result = local_bundle_adjustment(problem, LocalBAConfig())
    dist, ang = _error(result.T_world_cam[1], T_0_1)
    assert dist > 1e-3 or ang > 0.05, (dist, ang)  # underdetermined: the link is what fixes it


def test_links_to_keyframes_outside_the_problem_or_between_fixed_ones_are_ignored():
    problem, _, links = _two_keyframes()
    other = {7: DenseLink(7, 1, np.eye(4), np.array([[320.0, 240.0]]), np.array([2.0]))}
    assert add_dense_links(problem, other) == (problem, 0)
    fixed = dataclasses.replace(problem, fixed_kf_ids=np.array([0, 1]))
    assert add_dense_links(fixed, links)[1] == 0


def test_depth_grid_skips_invalid_and_edge_pixels():
    depth = np.full((480, 640), 2.0, np.float32)
    depth[:, :320] = 1.0  # a depth step at u = 320 (no grid column there)
    depth[:120, :] = 0.0  # invalid top rows
    uv, z = sample_depth_grid(depth, CAM.K, rows=4, cols=8)
    assert len(uv) == 3 * 8  # the first grid row (v = 60) has no depth
    assert np.all(uv[:, 1] > 120)
    np.testing.assert_allclose(z, np.where(uv[:, 0] < 320, 1.0, 2.0))
    depth[120:, 122:130] = 3.0  # an outline 2 px right of the grid column u = 120: in its 5x5 window
    uv2, _ = sample_depth_grid(depth, CAM.K, rows=4, cols=8)
    assert len(uv2) == 3 * 7 and not np.any(uv2[:, 0] == 120)
