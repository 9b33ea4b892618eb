r"""Extended Kalman filter backend: a constant-velocity camera-pose filter (NumPy).

The filter alternative to optimization (Barfoot, "State Estimation for Robotics", 2017, Sec. 4.2
and 7.3; Sola, "Quaternion kinematics for the error-state Kalman filter", 2017; Davison et al.
MonoSLAM, PAMI 2007, for the constant-velocity model). In the linear-Gaussian case it is the
Kalman filter; here the state lives on SE(3) x R^6, so it is linearized in an error state.

State ``x = (p, R, v, w)``: camera position ``p`` and orientation ``R`` in the world
(``T_world_cam = [R, p]``), linear velocity ``v`` (world frame) and angular velocity ``w`` (camera
frame). Error state ``dx = (dp, dth, dv, dw)`` (12), with ``R = R_hat Exp(dth)`` (right, body-frame
perturbation).

Motion model ``x_k = f(x_{k-1}, w_k)`` over ``dt``, driven by white accelerations
``a ~ N(0, q_a I)``, ``alpha ~ N(0, q_alpha I)`` (the noise ``w_k``):

    p_k = p + v dt + a dt^2 / 2        R_k = R Exp(w dt + alpha dt^2 / 2)
    v_k = v + a dt                     w_k = w + alpha dt

Its error-state Jacobian ``F = df/ddx`` (``J_r`` is the right Jacobian of SO(3)):

    dp_k  = dp + dt dv                 dth_k = Exp(w dt)^T dth + J_r(w dt) dt dw
    dv_k  = dv                         dw_k  = dw

and the process noise is the integrated continuous white-noise acceleration (Bar-Shalom et al.,
"Estimation with Applications to Tracking and Navigation", 2001, Sec. 6.2.2) per axis:
``Q_(p,v) = q_a [[dt^3/3, dt^2/2], [dt^2/2, dt]]``, the same with ``q_alpha`` for ``(th, w)``.

Observation ``z_k = h(x_k, v_k)``: the frontend's pose measurement (PnP or 3D-3D alignment)
``T_world_cam_meas = [R Exp(v_th), p + v_p]``, ``v = (v_p, v_th) ~ N(0, R_k)``. The innovation and
its Jacobian ``H = dh/ddx`` are

    y = (p_meas - p_hat, Log(R_hat^T R_meas)),      H = [[I, 0, 0, 0], [0, I, 0, 0]].

Predict / update (the Kalman equations, Joseph form for the covariance):

    x_k^- = f(x_{k-1}, 0),                P_k^- = F P_{k-1} F^T + Q
    S = H P^- H^T + R_k,  K = P^- H^T S^-1, dx = K y
    x_k = x_k^- (+) dx  (p += dp, R = R Exp(dth), v += dv, w += dw)
    P_k = (I - K H) P^- (I - K H)^T + K R_k K^T

Example:
    >>> ekf = PoseEKF()
    >>> _ = ekf.update(np.eye(4))          # the first measurement initializes the filter
    >>> T = ekf.predict(0.1)
    >>> T.shape
    (4, 4)
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from vslam.backend.config import EKFConfig
from vslam.errors import GeometryError
from vslam.geometry.lie import so3_exp

LOG = logging.getLogger(__name__)


def _skew(w: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def so3_log(R: np.ndarray) -> np.ndarray:
    """Rotation matrix -> rotation vector ``(3,)`` (stable near 0 and pi)."""
    R = np.asarray(R, dtype=float)
    c = np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)
    th = float(np.arccos(c))
    v = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if th < 1e-6:
        return 0.5 * v
    if np.pi - th < 1e-4:  # near pi: axis from the symmetric part
        A = (R + np.eye(3)) / 2.0
        axis = A[:, int(np.argmax(np.diag(A)))]
        axis = axis / np.linalg.norm(axis)
        if np.dot(axis, v) < 0:
            axis = -axis
        return th * axis
    return th / (2.0 * np.sin(th)) * v


def so3_right_jacobian(w: np.ndarray) -> np.ndarray:
    """``J_r(w) = I - (1 - cos t)/t^2 [w]_x + (t - sin t)/t^3 [w]_x^2`` (Barfoot eq. 7.77a, right form)."""
    th = float(np.linalg.norm(w))
    K = _skew(w)
    if th < 1e-6:
        return np.eye(3) - 0.5 * K + K @ K / 6.0
    return np.eye(3) - (1 - np.cos(th)) / th**2 * K + (th - np.sin(th)) / th**3 * K @ K


@dataclass
class EKFState:
    """The mean: ``T_world_cam (4, 4)``, ``velocity (3,)`` m/s (world), ``angular_velocity (3,)`` rad/s (camera)."""

    T_world_cam: np.ndarray
    velocity: np.ndarray
    angular_velocity: np.ndarray


def pose_covariance_from_inliers(n_inliers: int, reprojection_rmse_px: float, focal_px: float,
                                 mean_depth_m: float, min_rmse_px: float = 0.1) -> np.ndarray:
    """A rough ``(6, 6)`` measurement covariance (position, rotation) for a PnP pose.

    With ``n`` inliers of pixel error ``e``, the bearing error is ``e / f`` and averages down with
    ``sqrt(n)``: ``sigma_rot ~ e / (f sqrt(n))`` rad, ``sigma_pos ~ depth * e / (f sqrt(n))`` m (a
    first-order scaling, Hartley & Zisserman Sec. 5.2, not a full covariance propagation). ``e`` is
    at least ``min_rmse_px`` so that a perfect fit keeps a positive covariance.
    """
    if n_inliers <= 0 or not reprojection_rmse_px >= 0 or not focal_px > 0 or not mean_depth_m > 0:
        raise GeometryError(
            f"pose covariance needs n_inliers > 0, rmse >= 0, focal > 0, depth > 0; got "
            f"{n_inliers}, {reprojection_rmse_px}, {focal_px}, {mean_depth_m}"
        )
    e = max(reprojection_rmse_px, min_rmse_px) / (focal_px * np.sqrt(n_inliers))
    return np.diag([(mean_depth_m * e) ** 2] * 3 + [e**2] * 3)


class PoseEKF:
    """Constant-velocity error-state EKF on the camera pose (see the module docstring).

    ``update`` before any state exists initializes the pose from the measurement (velocities zero,
    with the configured initial uncertainty). Measurement covariances are ``(6, 6)`` in the order
    (position, rotation), or a scalar / ``(sigma_position, sigma_rotation)``.
    """

    def __init__(self, config: EKFConfig | None = None, T_world_cam: np.ndarray | None = None,
                 velocity: np.ndarray | None = None, angular_velocity: np.ndarray | None = None) -> None:
        self.config = config or EKFConfig()
        self._p = np.zeros(3)
        self._R = np.eye(3)
        self._v = np.zeros(3)
        self._w = np.zeros(3)
        self._P = np.eye(12)
        self.initialized = False
        self.rejected_updates = 0
        if T_world_cam is not None:
            self.initialize(T_world_cam, velocity, angular_velocity)

    def initialize(self, T_world_cam: np.ndarray, velocity: np.ndarray | None = None,
                   angular_velocity: np.ndarray | None = None) -> None:
        """Set the mean and the configured initial covariance."""
        T = np.asarray(T_world_cam, dtype=float)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise GeometryError(f"EKF pose must be a finite 4x4 matrix, got shape {T.shape}")
        U, _, Vt = np.linalg.svd(T[:3, :3])
        self._R = U @ Vt
        self._p = T[:3, 3].copy()
        self._v = np.zeros(3) if velocity is None else np.asarray(velocity, float).reshape(3).copy()
        self._w = np.zeros(3) if angular_velocity is None else np.asarray(angular_velocity, float).reshape(3).copy()
        c = self.config
        self._P = np.diag(
            [c.initial_sigma_position**2] * 3 + [c.initial_sigma_rotation**2] * 3
            + [c.initial_sigma_velocity**2] * 3 + [c.initial_sigma_angular_velocity**2] * 3
        )
        self.initialized = True

    @property
    def state(self) -> EKFState:
        return EKFState(self.T_world_cam, self._v.copy(), self._w.copy())

    @property
    def T_world_cam(self) -> np.ndarray:
        T = np.eye(4)
        T[:3, :3] = self._R
        T[:3, 3] = self._p
        return T

    @property
    def covariance(self) -> np.ndarray:
        """``(12, 12)`` covariance of ``(dp, dth, dv, dw)``."""
        return self._P.copy()

    def predict(self, dt: float) -> np.ndarray:
        """Propagate by ``dt`` seconds with the constant-velocity model; returns ``T_world_cam``."""
        if not self.initialized:
            raise GeometryError("EKF predict before the first pose: call initialize() or update() first")
        if not (np.isfinite(dt) and dt >= 0):
            raise GeometryError(f"EKF predict needs dt >= 0, got {dt}")
        phi = self._w * dt
        dR = so3_exp(phi)
        F = np.eye(12)
        F[0:3, 6:9] = dt * np.eye(3)
        F[3:6, 3:6] = dR.T
        F[3:6, 9:12] = so3_right_jacobian(phi) * dt
        qa, qw = self.config.accel_sigma**2, self.config.angular_accel_sigma**2
        Q = np.zeros((12, 12))
        for base, q in ((0, qa), (3, qw)):  # (p, v) and (th, w) blocks
            i, j = slice(base, base + 3), slice(base + 6, base + 9)
            Q[i, i] = q * dt**3 / 3.0 * np.eye(3)
            Q[i, j] = Q[j, i] = q * dt**2 / 2.0 * np.eye(3)
            Q[j, j] = q * dt * np.eye(3)
        self._p = self._p + self._v * dt
        self._R = self._R @ dR
        self._P = F @ self._P @ F.T + Q
        return self.T_world_cam

    def _measurement_cov(self, cov: np.ndarray | float | tuple | None) -> np.ndarray:
        c = self.config
        if cov is None:
            return np.diag([c.default_sigma_position**2] * 3 + [c.default_sigma_rotation**2] * 3)
        arr = np.asarray(cov, dtype=float)
        if arr.ndim == 0:
            return np.diag([float(arr) ** 2] * 6)
        if arr.shape == (2,):
            return np.diag([arr[0] ** 2] * 3 + [arr[1] ** 2] * 3)
        if arr.shape == (6, 6) and np.all(np.isfinite(arr)):
            return 0.5 * (arr + arr.T)
        raise GeometryError(f"EKF measurement covariance must be (6, 6), a sigma or (sigma_pos, sigma_rot); got {arr.shape}")

    def update(self, T_world_cam_meas: np.ndarray, cov: np.ndarray | float | tuple | None = None) -> np.ndarray:
        """Fuse a measured pose; returns the filtered ``T_world_cam`` (unchanged if the gate rejects it)."""
        T = np.asarray(T_world_cam_meas, dtype=float)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise GeometryError(f"EKF measurement must be a finite 4x4 pose, got shape {T.shape}")
        Rm = self._measurement_cov(cov)
        if not self.initialized:
            self.initialize(T)
            self._P[:6, :6] = Rm
            return self.T_world_cam
        y = np.concatenate([T[:3, 3] - self._p, so3_log(self._R.T @ T[:3, :3])])
        H = np.zeros((6, 12))
        H[:, :6] = np.eye(6)
        S = H @ self._P @ H.T + Rm
        S_inv_y = np.linalg.solve(S, y)
        d2 = float(y @ S_inv_y)
        if d2 > self.config.gate_chi2:
            self.rejected_updates += 1
            LOG.debug("EKF: measurement rejected (Mahalanobis^2 %.1f > %.1f)", d2, self.config.gate_chi2)
            return self.T_world_cam
        K = np.linalg.solve(S, H @ self._P).T  # P H^T S^-1 (S, P symmetric)
        dx = K @ y
        self._p = self._p + dx[0:3]
        self._R = self._R @ so3_exp(dx[3:6])
        self._v = self._v + dx[6:9]
        self._w = self._w + dx[9:12]
        IKH = np.eye(12) - K @ H
        self._P = IKH @ self._P @ IKH.T + K @ Rm @ K.T
        return self.T_world_cam
