"""The inertial-only residual of visual-inertial initialization (Campos et al., "Inertial-only
optimization for visual-inertial initialization", ICRA 2020, eq. 7-9; ORB-SLAM3's
``EdgeInertialGS``), with its analytic Jacobians, as a GTSAM ``CustomFactor``.

Between keyframes ``i`` and ``j`` (``dt`` apart) the IMU poses are fixed by the visual poses up to
the scale ``s``: ``R_i = R_wc_i R_cb`` and ``p_i = s c_i + R_wc_i t_cb`` (``c_i`` the camera centre
in visual units, ``T_cam_imu = [R_cb | t_cb]`` metric). The unknowns are the up direction ``u``
(a :class:`gtsam.Unit3`, 2 DoF: gravity ``g = -G u`` in the visual world frame), ``log s``
(monocular only), the metric IMU velocities ``v_i`` in the visual world frame, and the biases
``b_g``, ``b_a`` (one for the window). The residual, ordered as GTSAM's preintegration covariance
(rotation, position, velocity; Forster et al. T-RO 2017 eq. 45)::

    r_R = Log(dR(b)^T R_i^T R_j)
    r_p = R_i^T (p_j - p_i - v_i dt - g dt^2 / 2) - dp(b)
    r_v = R_i^T (v_j - v_i - g dt) - dv(b)

The deltas are corrected for the bias to first order, as GTSAM's ``biasCorrectedDelta`` does
(tangent preintegration: ``theta(b) = theta_0 + H_theta db``, ``dR = Exp(theta)``); the matrices
``H`` are read off GTSAM's own ``predict`` (exact: the correction is linear in the bias).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vslam.geometry.lie import so3_exp, so3_log
from vslam.inertial import ImuBias, ImuCalibration, ImuMeasurements, preintegrate

#: Bias step of the central differences that read GTSAM's (linear) bias correction.
_BIAS_STEP = 1e-3


@dataclass(frozen=True)
class ImuInterval:
    """Preintegrated IMU motion between two keyframes with its first-order bias model.

    ``theta0, dp0, dv0 (3,)`` at the linearization bias ``bias0 (6,)`` (``b_g``, ``b_a``),
    ``H (9, 6)`` rows ``(theta, p, v)`` by columns ``(b_g, b_a)``, ``cov (9, 9)`` GTSAM's
    preintegration covariance (rotation, position, velocity), ``dt`` seconds.
    """

    theta0: np.ndarray
    dp0: np.ndarray
    dv0: np.ndarray
    H: np.ndarray
    bias0: np.ndarray
    cov: np.ndarray
    dt: float

    def deltas(self, b: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(theta, dR, dp, dv)`` at bias ``b = (b_g, b_a)`` (first order, GTSAM's correction)."""
        d = self.H @ (b - self.bias0)
        theta = self.theta0 + d[:3]
        return theta, so3_exp(theta), self.dp0 + d[3:6], self.dv0 + d[6:]


def _pure_deltas(pim, bias: np.ndarray) -> np.ndarray:
    """``(theta, dp, dv)`` (9,) from GTSAM's ``predict`` from rest at the origin, with zero gravity
    in the parameters: the bias-corrected deltas themselves."""
    import gtsam

    s = pim.predict(gtsam.NavState(), gtsam.imuBias.ConstantBias(bias[3:], bias[:3]))
    return np.concatenate([so3_log(np.asarray(s.attitude().matrix())), np.asarray(s.position()),
                           np.asarray(s.velocity())])


def imu_interval(imu: ImuMeasurements, t0: float, t1: float, params, bias: ImuBias) -> ImuInterval:
    """The :class:`ImuInterval` from ``t0`` to ``t1`` (IMU clock) preintegrated at ``bias``;
    ``params`` must have zero gravity (``make_params(calib, np.zeros(3))``)."""
    pim = preintegrate(imu, t0, t1, params, bias)
    b0 = np.concatenate([bias.gyro, bias.accel])
    base = _pure_deltas(pim, b0)
    H = np.empty((9, 6))
    for k in range(6):
        e = np.zeros(6)
        e[k] = _BIAS_STEP
        H[:, k] = (_pure_deltas(pim, b0 + e) - _pure_deltas(pim, b0 - e)) / (2 * _BIAS_STEP)
    cov = np.asarray(pim.preintMeasCov())[:9, :9]
    return ImuInterval(base[:3], base[3:6], base[6:], H, b0, 0.5 * (cov + cov.T), float(pim.deltaTij()))


def right_jacobian(w: np.ndarray) -> np.ndarray:
    """SO(3) right Jacobian ``Jr(w)`` (Sola eq. 143: ``Jr(w) = Jl(-w)``)."""
    a = float(np.linalg.norm(w))
    W = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
    if a < 1e-8:
        return np.eye(3) - 0.5 * W
    return np.eye(3) - (1 - np.cos(a)) / a**2 * W + (a - np.sin(a)) / a**3 * (W @ W)


def right_jacobian_inv(w: np.ndarray) -> np.ndarray:
    """``Jr(w)^-1`` (Sola eq. 144 with ``w -> -w``)."""
    a = float(np.linalg.norm(w))
    W = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
    if a < 1e-8:
        return np.eye(3) + 0.5 * W
    return np.eye(3) + 0.5 * W + (1 / a**2 - (1 + np.cos(a)) / (2 * a * np.sin(a))) * (W @ W)


@dataclass(frozen=True)
class KeyframePair:
    """The fixed visual part of one interval: IMU rotations ``R_i, R_j`` (world <- IMU), camera
    centres ``c_i, c_j`` (visual units) and lever arms ``q_i = R_wc_i t_cb`` (metres)."""

    R_i: np.ndarray
    R_j: np.ndarray
    c_i: np.ndarray
    c_j: np.ndarray
    q_i: np.ndarray
    q_j: np.ndarray


def residual(pair: KeyframePair, itv: ImuInterval, up: np.ndarray, basis: np.ndarray, log_s: float,
             v_i: np.ndarray, v_j: np.ndarray, b: np.ndarray, gravity: float, jacobians: bool = False):
    """The 9-vector ``(r_R, r_p, r_v)`` (module docstring) and, with ``jacobians``, the blocks
    ``(d/du (9, 2), d/dlog_s (9, 1), d/dv_i, d/dv_j (9, 3), d/db_g, d/db_a (9, 3))``; ``u`` moves
    along ``basis (3, 2)`` (GTSAM's ``Unit3`` retraction at 0)."""
    theta, dR, dp, dv = itv.deltas(b)
    dt, Rt, s = itv.dt, pair.R_i.T, float(np.exp(log_s))
    g = -gravity * up
    r_R = so3_log(dR.T @ Rt @ pair.R_j)
    dpos = s * (pair.c_j - pair.c_i) + pair.q_j - pair.q_i
    r_p = Rt @ (dpos - v_i * dt - 0.5 * g * dt * dt) - dp
    r_v = Rt @ (v_j - v_i - g * dt) - dv
    r = np.concatenate([r_R, r_p, r_v])
    if not jacobians:
        return r, None
    J_rot = -right_jacobian_inv(r_R) @ so3_exp(r_R).T @ right_jacobian(theta) @ itv.H[:3]
    J_b = np.vstack([J_rot, -itv.H[3:6], -itv.H[6:]])
    J_u = np.vstack([np.zeros((3, 2)), 0.5 * gravity * dt * dt * Rt @ basis, gravity * dt * Rt @ basis])
    J_s = np.concatenate([np.zeros(3), s * Rt @ (pair.c_j - pair.c_i), np.zeros(3)])[:, None]
    Z = np.zeros((3, 3))
    J_vi = np.vstack([Z, -dt * Rt, -Rt])
    J_vj = np.vstack([Z, Z, Rt])
    return r, (J_u, J_s, J_vi, J_vj, J_b[:, :3], J_b[:, 3:])


def inertial_factor(pair: KeyframePair, itv: ImuInterval, keys: dict, gravity: float, log_s_fixed: float | None):
    """A ``gtsam.CustomFactor`` of :func:`residual` on the keys ``u, [s,] v_i, v_j, bg, ba``
    (``keys`` maps those names to GTSAM keys; ``log_s_fixed`` not None: the scale is a constant
    and ``s`` is not a key), whitened by the interval's preintegration covariance."""
    import gtsam

    names = ["u"] + (["s"] if log_s_fixed is None else []) + ["v_i", "v_j", "bg", "ba"]
    noise = gtsam.noiseModel.Gaussian.Covariance(itv.cov)

    def error(_this, values, H):
        u = values.atUnit3(keys["u"])
        log_s = log_s_fixed if log_s_fixed is not None else float(values.atVector(keys["s"])[0])
        b = np.concatenate([values.atVector(keys["bg"]), values.atVector(keys["ba"])])
        r, J = residual(pair, itv, np.asarray(u.point3()), np.asarray(u.basis()), log_s,
                        values.atVector(keys["v_i"]), values.atVector(keys["v_j"]), b, gravity, H is not None)
        if H is not None:
            blocks = [J[0]] + ([J[1]] if log_s_fixed is None else []) + list(J[2:])
            for k, block in enumerate(blocks):
                H[k] = block
        return r

    return gtsam.CustomFactor(noise, [keys[n] for n in names], error)


def make_pair(T_world_cam_i: np.ndarray, T_world_cam_j: np.ndarray, calib: ImuCalibration) -> KeyframePair:
    """The :class:`KeyframePair` of two visual poses (``T_world_cam``, visual units)."""
    R_cb, t_cb = calib.T_cam_imu[:3, :3], calib.T_cam_imu[:3, 3]
    Ti, Tj = T_world_cam_i, T_world_cam_j
    return KeyframePair(Ti[:3, :3] @ R_cb, Tj[:3, :3] @ R_cb, Ti[:3, 3], Tj[:3, 3], Ti[:3, :3] @ t_cb,
                        Tj[:3, :3] @ t_cb)
