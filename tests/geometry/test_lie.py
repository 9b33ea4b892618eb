"""SO(3)/SE(3)/Sim(3) helpers against closed forms, SciPy and evo."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from vslam.errors import GeometryError
from vslam.geometry import (
    angle_between_deg,
    compose,
    hat,
    interpolate_pose,
    interpolate_trajectory,
    inv_T,
    inv_se3,
    is_rotation,
    make_sim3,
    make_T,
    project_to_so3,
    quat_to_rotmat,
    relative_T,
    rotation_angle_deg,
    rotation_error_deg,
    rotmat_to_quat,
    se3_exp,
    se3_log,
    sim3_decompose,
    slerp_rotation,
    so3_exp,
    so3_log,
    transform_points,
    vee,
)

RNG = np.random.default_rng(60)
ROTVECS = np.vstack([
    RNG.normal(size=(20, 3)),
    [[0, 0, 0], [1e-12, 0, 0], [0, 0, np.pi - 1e-9], [np.pi, 0, 0], [0, 3.0, 0]],
])


def test_so3_exp_log_match_scipy():
    R = so3_exp(ROTVECS)
    np.testing.assert_allclose(R, Rotation.from_rotvec(ROTVECS).as_matrix(), atol=1e-12)
    w = so3_log(R)
    # log is the inverse of exp up to the 2 pi wrap (compare rotations, not vectors)
    np.testing.assert_allclose(so3_exp(w), R, atol=1e-9)
    small = ROTVECS[np.linalg.norm(ROTVECS, axis=1) < np.pi - 1e-6]
    np.testing.assert_allclose(so3_log(so3_exp(small)), small, atol=1e-9)
    np.testing.assert_allclose(vee(hat(ROTVECS)), ROTVECS)


def test_quaternions_match_scipy():
    R = so3_exp(ROTVECS)
    q = rotmat_to_quat(R)
    q_sp = Rotation.from_matrix(R).as_quat()
    q_sp *= np.where(q_sp[:, 3:] < 0, -1, 1)
    np.testing.assert_allclose(np.abs(np.sum(q * q_sp, axis=1)), 1.0, atol=1e-12)
    np.testing.assert_allclose(quat_to_rotmat(q), R, atol=1e-12)
    with pytest.raises(GeometryError):
        quat_to_rotmat(np.zeros(4))


def test_se3_exp_log_roundtrip_and_inverse():
    for xi in RNG.normal(size=(10, 6)):
        T = se3_exp(xi)
        np.testing.assert_allclose(se3_log(T), xi, atol=1e-9)
        np.testing.assert_allclose(inv_T(T) @ T, np.eye(4), atol=1e-12)
    Ts = np.stack([se3_exp(x) for x in RNG.normal(size=(4, 6))])
    np.testing.assert_allclose(inv_T(Ts) @ Ts, np.broadcast_to(np.eye(4), (4, 4, 4)), atol=1e-12)
    # the rigid inverse: batched (the evaluation's path) and per frame give the same poses
    np.testing.assert_allclose(inv_se3(Ts) @ Ts, np.broadcast_to(np.eye(4), (4, 4, 4)), atol=1e-12)
    np.testing.assert_allclose(inv_se3(Ts[1]), inv_se3(Ts)[1], atol=1e-15)
    np.testing.assert_allclose(inv_se3(Ts[None]), inv_se3(Ts)[None], atol=0)
    # pure translation: exp of (rho, 0) is a translation by rho
    np.testing.assert_allclose(se3_exp(np.r_[1.0, 2.0, 3.0, 0, 0, 0]), make_T(np.eye(3), [1, 2, 3]))


def test_sim3_compose_inverse_and_transform():
    R = so3_exp(np.array([0.1, -0.2, 0.3]))
    S = make_sim3(2.5, R, np.array([1.0, 0.0, -1.0]))
    s, R2, t2 = sim3_decompose(S)
    assert abs(s - 2.5) < 1e-12 and np.allclose(R2, R) and np.allclose(t2, [1, 0, -1])
    np.testing.assert_allclose(inv_T(S) @ S, np.eye(4), atol=1e-12)
    X = RNG.normal(size=(5, 3))
    np.testing.assert_allclose(transform_points(S, X), 2.5 * X @ R.T + [1, 0, -1])
    np.testing.assert_allclose(transform_points(inv_T(S), transform_points(S, X)), X, atol=1e-12)
    A, B = se3_exp(RNG.normal(size=6)), se3_exp(RNG.normal(size=6))
    np.testing.assert_allclose(compose(A, B, S), A @ B @ S)
    np.testing.assert_allclose(relative_T(A, B), np.linalg.inv(A) @ B, atol=1e-12)


def test_angles_and_projection():
    R = so3_exp(np.array([0.0, 0.0, np.radians(30)]))
    assert abs(rotation_angle_deg(R) - 30) < 1e-10
    assert abs(rotation_angle_deg(so3_exp(np.array([1e-9, 0, 0]))) - np.degrees(1e-9)) < 1e-15
    assert abs(rotation_angle_deg(so3_exp(np.array([np.pi, 0, 0]))) - 180) < 1e-6
    assert abs(rotation_error_deg(make_T(R, [1, 2, 3]), np.eye(4)) - 30) < 1e-10
    assert abs(angle_between_deg(np.array([1.0, 0, 0]), np.array([0, 2.0, 0])) - 90) < 1e-12
    noisy = R + 1e-3 * RNG.normal(size=(3, 3))
    assert is_rotation(project_to_so3(noisy)) and not is_rotation(noisy)
    assert rotation_error_deg(project_to_so3(noisy), R) < 0.5


def test_interpolation_matches_scipy_slerp():
    T0, T1 = se3_exp(RNG.normal(size=6)), se3_exp(RNG.normal(size=6))
    alphas = np.array([0.0, 0.25, 0.5, 1.0])
    Ti = interpolate_pose(T0, T1, alphas)
    ref = Slerp([0, 1], Rotation.from_matrix(np.stack([T0[:3, :3], T1[:3, :3]])))(alphas).as_matrix()
    np.testing.assert_allclose(Ti[:, :3, :3], ref, atol=1e-10)
    np.testing.assert_allclose(Ti[:, :3, 3], (1 - alphas)[:, None] * T0[:3, 3] + alphas[:, None] * T1[:3, 3])
    np.testing.assert_allclose(slerp_rotation(T0[:3, :3], T1[:3, :3], 0.25), ref[1], atol=1e-10)
    Tq = interpolate_trajectory([0.0, 2.0, 3.0], np.stack([T0, T1, T0]), [0.5, 2.0, 2.5])
    np.testing.assert_allclose(Tq[0], interpolate_pose(T0, T1, 0.25), atol=1e-10)
    np.testing.assert_allclose(Tq[1], T1, atol=1e-10)
    np.testing.assert_allclose(Tq[2], interpolate_pose(T1, T0, 0.5), atol=1e-10)
    with pytest.raises(GeometryError, match="outside"):
        interpolate_trajectory([0.0, 1.0], np.stack([T0, T1]), [1.5])
