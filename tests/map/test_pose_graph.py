"""SE(3) / Sim(3) pose graphs on simulated loops with drift (vslam.backend.drift_demo.simulate_loop)."""
from __future__ import annotations

import numpy as np
import pytest

from vslam.backend.drift_demo import ate_rmse, close_loop, simulate_loop
from vslam.geometry.lie import make_sim3, sim3_decompose, so3_exp
from vslam.map.pose_graph import correct_points, optimize_pose_graph
from vslam.errors import GeometryError


def test_se3_loop_closure_reduces_ate_5x():
    sim = simulate_loop(n_poses=100, noise=1.0, seed=0)
    before = ate_rmse(sim.T_odom, sim.T_true)
    T = close_loop(sim)
    after = ate_rmse(T, sim.T_true)
    assert before > 0.5  # ~1 m of drift on a 62 m loop
    assert after < before / 5.0, (before, after)  # measured 1.01 -> 0.022 m
    np.testing.assert_allclose(T[0], sim.T_odom[0], atol=1e-12)  # the fixed node stays
    assert np.linalg.norm(T[-1, :3, 3] - sim.T_true[-1, :3, 3]) < 0.01


def test_sim3_corrects_scale_drift():
    sim = simulate_loop(n_poses=100, noise=0.5, scale_drift=0.005, seed=1)
    assert sim.scale[-1] > 1.6  # the local map at the end is 64 % too large
    S = close_loop(sim, sim3=True)
    s_end, _, _ = sim3_decompose(S[-1])
    # the end node's scale undoes the drift: s_end * drift = 1 within 2 %
    assert abs(s_end * sim.scale[-1] - 1.0) < 0.02, s_end * sim.scale[-1]
    before = ate_rmse(sim.T_odom, sim.T_true)
    after = ate_rmse(S, sim.T_true)
    assert after < before / 5.0, (before, after)  # measured 3.3 -> 0.07 m
    # an SE(3) graph cannot absorb scale drift
    T_se3 = close_loop(sim, sim3=False)
    assert ate_rmse(T_se3, sim.T_true) > 5 * after


def test_correct_points_follows_the_reference_keyframe():
    # a point seen from a drifted, scale-drifted keyframe lands at its true position after Sim(3) correction
    sim = simulate_loop(n_poses=100, noise=0.5, scale_drift=0.005, seed=1)
    S = close_loop(sim, sim3=True)
    k = 80
    X_cam_true = np.array([[0.5, -0.2, 4.0]])
    X_true = X_cam_true @ sim.T_true[k, :3, :3].T + sim.T_true[k, :3, 3]
    # in the drifted map the point sits at the drifted local scale in front of the drifted pose
    X_drift = (sim.scale[k] * X_cam_true) @ sim.T_odom[k, :3, :3].T + sim.T_odom[k, :3, 3]
    X_fixed = correct_points(X_drift, np.array([k]), sim.T_odom, S)
    assert np.linalg.norm(X_drift - X_true) > 1.0
    assert np.linalg.norm(X_fixed - X_true) < 0.15, np.linalg.norm(X_fixed - X_true)  # measured 4.8 m -> 0.09 m
    with pytest.raises(GeometryError):
        correct_points(X_drift, np.array([500]), sim.T_odom, S)


def test_small_chain_is_exact_and_information_weights_count():
    T = np.tile(np.eye(4), (3, 1, 1))
    T[1, 0, 3], T[2, 0, 3] = 1.1, 2.3
    step = np.eye(4)
    step[0, 3] = 1.0
    res = optimize_pose_graph(T, [(0, 1, step), (1, 2, step), (0, 2, step @ step)])
    np.testing.assert_allclose(res.T_world_cam[:, 0, 3], [0.0, 1.0, 2.0], atol=1e-9)
    np.testing.assert_allclose(res.scales, 1.0)
    # conflicting edges: the heavily weighted one wins
    long = step @ step
    long[0, 3] = 2.2
    res = optimize_pose_graph(T, [(0, 1, step), (1, 2, step), (0, 2, long, 1e4)])
    assert abs(res.T_world_cam[2, 0, 3] - 2.2) < 1e-3
    assert res.final_error < res.initial_error


def test_sim3_helpers_round_trip():
    R = so3_exp(np.array([[0.1, -0.2, 0.3]]))[0]
    S = make_sim3(1.7, R, np.array([1.0, 2.0, 3.0]))
    s2, R2, t2 = sim3_decompose(S)
    np.testing.assert_allclose(R2, R, atol=1e-12)
    np.testing.assert_allclose(t2, [1.0, 2.0, 3.0])
    assert abs(s2 - 1.7) < 1e-12
    # a graph with one Sim(3) edge reproduces it exactly
    res = optimize_pose_graph(np.tile(np.eye(4), (2, 1, 1)), [(0, 1, S)], sim3=True)
    np.testing.assert_allclose(res.S_world_cam[1], S, atol=1e-8)
    assert abs(res.scales[1] - 1.7) < 1e-8


def test_bad_input_raises():
    T = np.tile(np.eye(4), (2, 1, 1))
    with pytest.raises(GeometryError):
        optimize_pose_graph(T, [(0, 5, np.eye(4))])
    with pytest.raises(GeometryError):
        optimize_pose_graph(T, [])
    with pytest.raises(GeometryError):
        optimize_pose_graph(T, [(0, 1, np.eye(4))], fixed=[])
    with pytest.raises(GeometryError):
        optimize_pose_graph(T, [(0, 1, np.eye(4), np.eye(3))])


def test_metis_ordering_gives_the_colamd_solution_on_a_dense_graph():
    """The essential graph is eliminated in METIS order (fast on densely covisible graphs); it must
    reach the same optimum as GTSAM's default COLAMD ordering."""
    import gtsam

    from vslam.map.config import PoseGraphConfig
    from vslam.map.pose_graph import ELIMINATION_ORDERING, build_pose_graph

    assert ELIMINATION_ORDERING == "METIS"
    sim = simulate_loop(n_poses=60, noise=1.0, seed=3)
    T_inv = np.linalg.inv(sim.T_odom)
    edges = [(i, j, T_inv[i] @ sim.T_odom[j]) for i in range(60) for j in range(i + 1, min(i + 8, 60))]
    edges.append((0, 59, np.linalg.inv(sim.T_true[0]) @ sim.T_true[59], 10.0))
    res = optimize_pose_graph(sim.T_odom, edges, fixed=[0])
    graph, values, _ = build_pose_graph(sim.T_odom, edges, [0], False, PoseGraphConfig())
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(100)
    params.setRelativeErrorTol(1e-8)
    colamd = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
    ref = np.stack([colamd.atPose3(k).matrix() for k in range(60)])
    assert res.final_error < 0.5 * res.initial_error
    np.testing.assert_allclose(res.T_world_cam, ref, atol=1e-9)


def test_nearest_rotations_equal_one_svd_at_a_time_to_the_bit():
    """The batched SVD of the pose-graph build gives each matrix's ``U @ Vt`` as one SVD at a time did."""
    from vslam.map.pose_graph import nearest_rotations

    rng = np.random.default_rng(0)
    M = np.stack([so3_exp(rng.normal(size=3)) for _ in range(300)]) + rng.normal(scale=1e-6, size=(300, 3, 3))
    got = nearest_rotations(M)
    ref = []
    for m in M:
        U, _, Vt = np.linalg.svd(m)
        ref.append(U @ Vt)
    assert all(np.array_equal(g, r) for g, r in zip(got, ref))
    assert max(np.abs(g - m).max() for g, m in zip(got, M)) > 1e-7  # the inputs were not exact rotations


def _build_one_edge_at_a_time(T_world_cam, edges, fixed, sim3, config):
    """The SE(3) graph as build_pose_graph made it before its batched SVDs and shared noise models
    (one SVD and one noise model per node / edge): the reference of the test below."""
    import gtsam

    from vslam.map.pose_graph import _noise

    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    for k in range(len(T_world_cam)):
        U, _, Vt = np.linalg.svd(T_world_cam[k, :3, :3])
        values.insert(k, gtsam.Pose3(gtsam.Rot3(U @ Vt), T_world_cam[k, :3, 3]))
    for e in edges:
        Z = np.asarray(e[2], float)
        U, _, Vt = np.linalg.svd(Z[:3, :3])
        graph.add(gtsam.BetweenFactorPose3(int(e[0]), int(e[1]), gtsam.Pose3(gtsam.Rot3(U @ Vt), Z[:3, 3]),
                                           _noise(e[3] if len(e) == 4 else None, 6, config)))
    for k in sorted(set(fixed)):
        graph.add(gtsam.NonlinearEqualityPose3(k, values.atPose3(k)))
    return graph, values, len(edges)


def test_se3_graph_equals_the_one_edge_at_a_time_build_to_the_bit(monkeypatch):
    """Batched SVDs and shared noise models (default, scalar-weighted; a full information matrix
    gets its own) solve to the same poses, to the bit, as the per-edge build they replaced."""
    from vslam.map import pose_graph

    sim = simulate_loop(n_poses=40, noise=1.0, seed=3)
    T = sim.T_odom
    rng = np.random.default_rng(1)
    edges = [(i, i + 1, np.linalg.inv(T[i]) @ T[i + 1]) for i in range(len(T) - 1)]
    edges += [(i, i + 5, np.linalg.inv(sim.T_true[i]) @ sim.T_true[i + 5], float(rng.uniform(0.5, 2.0)))
              for i in range(0, len(T) - 5, 3)]
    edges.append((0, len(T) - 1, np.linalg.inv(sim.T_true[0]) @ sim.T_true[-1], 10.0))
    edges.append((2, 30, np.linalg.inv(sim.T_true[2]) @ sim.T_true[30], np.diag(rng.uniform(1e2, 1e4, 6))))
    new = optimize_pose_graph(T, edges, fixed=[0])
    monkeypatch.setattr(pose_graph, "build_pose_graph", _build_one_edge_at_a_time)
    ref = optimize_pose_graph(T, edges, fixed=[0])
    assert np.array_equal(new.S_world_cam, ref.S_world_cam) and new.iterations == ref.iterations
    assert ate_rmse(new.T_world_cam, sim.T_true) < ate_rmse(T, sim.T_true) / 3
