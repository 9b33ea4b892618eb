"""ATE/RPE building blocks on synthetic trajectories with exact answers, and evo parity of the pairs."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from vslam.errors import TrajectoryError
from vslam.eval.metrics import (
    ErrorStats, align, ate_errors, rotation_angle, rpe_errors, rpe_pairs,
)


def wavy_path(n: int = 200, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 4 * np.pi, n)
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, 3] = np.stack([3 * np.cos(t), 2 * np.sin(t), 0.3 * t], axis=1) + rng.normal(0, 0.01, (n, 3))
    T[:, :3, :3] = Rotation.from_rotvec(np.stack([0.1 * np.sin(t), 0.2 * np.cos(t), t], 1)).as_matrix()
    return T


def sim3(T: np.ndarray, R: np.ndarray, t: np.ndarray, s: float) -> np.ndarray:
    out = T.copy()
    out[:, :3, :3] = R @ T[:, :3, :3]
    out[:, :3, 3] = s * T[:, :3, 3] @ R.T + t
    return out


def test_error_stats():
    st = ErrorStats.of(np.array([3.0, 4.0]))
    assert st.rmse == pytest.approx(np.sqrt(12.5)) and st.mean == 3.5 and st.std == 0.5
    assert st.max == 4 and st.min == 3 and st.median == 3.5 and st.sse == 25 and st.count == 2


def test_rotation_angle_exact_and_near_zero():
    angles = np.array([0.0, 1e-9, 1e-4, 0.3, 2.0, np.pi - 1e-6, np.pi])
    R = Rotation.from_rotvec(np.outer(angles, [1, 2, 2]) / 3).as_matrix()
    np.testing.assert_allclose(rotation_angle(R), angles, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("mode", ["se3", "sim3"])
def test_alignment_recovers_known_similarity(mode):
    T_gt = wavy_path()
    R = Rotation.from_rotvec([0.3, -1.0, 0.5]).as_matrix()
    s = 0.37 if mode == "sim3" else 1.0
    # est = S^-1 gt, so aligning est recovers S exactly and ATE is 0.
    T_est = sim3(T_gt, R.T, -R.T @ np.array([1.0, -2.0, 0.5]) / s, 1 / s)
    a = align(T_est, T_gt, mode)
    np.testing.assert_allclose(a.R, R, atol=1e-10)
    assert a.s == pytest.approx(s, rel=1e-10)
    np.testing.assert_allclose(a.t, [1.0, -2.0, 0.5], atol=1e-9)
    assert ate_errors(a.apply(T_est), T_gt).max() < 1e-9
    T_gt_est = a.T_gt_est
    np.testing.assert_allclose((T_gt_est @ T_est[:, :, :])[:, :3, 3], T_gt[:, :3, 3], atol=1e-9)


def test_align_first_n_and_none_and_origin():
    T_gt = wavy_path()
    T_est = T_gt.copy()
    T_est[:, :3, 3] += np.array([1.0, 0, 0])  # constant shift
    T_est[100:, :3, 3] += 5.0  # second half off
    a = align(T_est, T_gt, "se3", n_first=50)
    np.testing.assert_allclose(a.t, [-1.0, 0, 0], atol=1e-9)
    assert ate_errors(a.apply(T_est), T_gt)[:100].max() < 1e-9
    assert align(T_est, T_gt, "none").t.tolist() == [0, 0, 0]
    o = align(T_est, T_gt, "origin")
    assert ate_errors(o.apply(T_est), T_gt)[0] < 1e-12
    with pytest.raises(TrajectoryError, match="unknown alignment"):
        align(T_est, T_gt, "affine")
    with pytest.raises(TrajectoryError, match="cannot align with sim3 using 2"):
        align(T_est[:2], T_gt[:2], "sim3")


def test_rpe_constant_drift_known_answer():
    """Estimate moves 1.1x as far each step along x: RPE translation = 0.1 * step, rotation 0."""
    n = 50
    T_gt = np.tile(np.eye(4), (n, 1, 1))
    T_gt[:, 0, 3] = 0.2 * np.arange(n)
    T_est = T_gt.copy()
    T_est[:, 0, 3] *= 1.1
    pairs = rpe_pairs(T_est, 2)
    t_err, r_err = rpe_errors(T_est, T_gt, pairs)
    assert len(pairs) == 24
    np.testing.assert_allclose(t_err, 0.1 * 0.4, atol=1e-12)
    np.testing.assert_allclose(r_err, 0.0, atol=1e-12)
    # Yaw drift of 0.5 deg per frame, positions exact: rotation error 0.5 deg per pair.
    T_est = T_gt.copy()
    T_est[:, :3, :3] = Rotation.from_euler("z", 0.5 * np.arange(n)[:, None], degrees=True).as_matrix()
    t_err, r_err = rpe_errors(T_est, T_gt, rpe_pairs(T_est, 1))
    np.testing.assert_allclose(r_err, 0.5, atol=1e-9)


@pytest.mark.parametrize("delta,unit,all_pairs", [
    (1, "frames", False), (3, "frames", False), (3, "frames", True),
    (0.5, "m", False), (2.0, "m", False), (0.5, "m", True),
])
def test_rpe_pairs_match_evo(evo, delta, unit, all_pairs):
    T = wavy_path(300, seed=1)
    poses = list(T)
    if unit == "frames":
        ref = evo.filters.filter_pairs_by_index(poses, int(delta), all_pairs)
    else:
        ref = evo.filters.filter_pairs_by_path(poses, delta, 0.1 * delta, all_pairs)
    ours = rpe_pairs(T, delta, unit, all_pairs)
    assert len(ref) > 10
    np.testing.assert_array_equal(ours, np.array(ref))


def test_rpe_pairs_bad_delta():
    T = wavy_path(10)
    with pytest.raises(TrajectoryError, match="whole number"):
        rpe_pairs(T, 1.5, "frames")
    with pytest.raises(TrajectoryError, match="unknown RPE delta unit"):
        rpe_pairs(T, 1, "deg")
    assert len(rpe_pairs(T, 100, "m")) == 0


@pytest.mark.parametrize("mode", ["se3", "sim3"])
def test_alignment_of_a_planar_trajectory_is_a_rotation(mode):
    # a ground-plane trajectory (z = 0): the positions are coplanar, and an alignment without
    # Umeyama's reflection guard comes out mirrored for about half of the rotations
    n = 60
    t = np.linspace(0, 2 * np.pi, n)
    T_gt = np.tile(np.eye(4), (n, 1, 1))
    T_gt[:, :3, 3] = np.stack([4 * np.cos(t), 2.5 * np.sin(2 * t), np.zeros(n)], axis=1)
    T_gt[:, :3, :3] = Rotation.from_rotvec(np.outer(t, [0, 0, 1])).as_matrix()
    s = 0.6 if mode == "sim3" else 1.0
    for k in range(12):
        R = Rotation.from_rotvec(np.random.default_rng(k).normal(size=3)).as_matrix()
        T_est = sim3(T_gt, R.T, -R.T @ np.array([0.5, 1.0, -1.5]) / s, 1 / s)
        a = align(T_est, T_gt, mode)
        assert np.linalg.det(a.R) == pytest.approx(1.0, abs=1e-9), k
        np.testing.assert_allclose(a.R, R, atol=1e-9)
        assert ate_errors(a.apply(T_est), T_gt).max() < 1e-9
