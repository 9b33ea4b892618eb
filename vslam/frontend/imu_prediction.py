"""The IMU's pose prediction for the next frame, replacing the constant-velocity model once the
IMU is initialized (ORB-SLAM3's ``Tracking::PredictStateIMU``, without its inertial pose optimization).

State: the last tracked frame's time ``t_i``, its IMU pose ``(R_i, p_i)`` (``T_world_imu =
T_world_cam @ T_cam_imu``), the IMU velocity ``v_i`` (world frame, m/s) and the biases of the
initialization. The world is the gravity-aligned one (z up, gravity ``g = (0, 0, -9.81)``).

Prediction (Forster et al., "On-Manifold Preintegration for Real-Time Visual-Inertial Odometry",
T-RO 2017, eq. 33 solved for ``j``; the deltas ``dR, dv, dp`` preintegrated from ``t_i`` to
``t_j`` at the biases, :func:`vslam.inertial.preintegrated_delta`)::

    R_j = R_i dR
    v_j = v_i + g dt + R_i dv
    p_j = p_i + v_i dt + 1/2 g dt^2 + R_i dp

and ``T_world_cam_j = T_world_imu_j @ T_imu_cam``.

Velocity update, once frame ``j`` is tracked at ``(R_j', p_j')``: the position equation above
gives the velocity at ``i`` that the two tracked positions imply, ``v_i' = (p_j' - p_i - 1/2 g dt^2
- R_i dp) / dt``, and the velocity equation carries it to ``j``: ``v_j = v_i' + g dt + R_i dv``
(equivalently ``v_j = v_j^pred + (p_j' - p_j^pred) / dt``). The rotation and position of the new
state are the tracked ones, so tracking errors do not accumulate in the prediction.
"""
from __future__ import annotations

import logging

import numpy as np

from vslam.errors import DatasetError
from vslam.geometry.lie import inv_se3
from vslam.inertial import (
    ImuBias, ImuCalibration, ImuDelta, ImuMeasurements, gravity_vector, make_params, predict, preintegrated_delta,
)

log = logging.getLogger(__name__)


class ImuPredictor:
    """Predicts ``T_world_cam`` of the next frame from the IMU (module docstring).

    Args:
        imu, calib: samples and calibration (``T_imu_cam`` of the tracked camera).
        bias: the biases to preintegrate with (from the initialization).
        timestamp: time of the starting state (camera clock); T_world_cam: its pose (gravity-aligned
            world); velocity: its IMU velocity in that world, m/s.
    """

    def __init__(self, imu: ImuMeasurements, calib: ImuCalibration, bias: ImuBias, timestamp: float,
                 T_world_cam: np.ndarray, velocity: np.ndarray) -> None:
        self.imu = imu
        self.calib = calib
        self.bias = bias
        self.g = gravity_vector(calib.gravity)
        self._params = make_params(calib, self.g)
        self._T_cam_imu = inv_se3(calib.T_imu_cam)
        self.t = float(timestamp)
        self.T_world_cam = np.array(T_world_cam, float)
        self.v = np.asarray(velocity, float).reshape(3).copy()
        self.active = True
        self.n_predicted = 0
        self._cache: tuple[float, ImuDelta] | None = None

    def _delta(self, t: float) -> ImuDelta | None:
        """The preintegrated deltas from the state's time to ``t`` (None when the IMU does not cover it)."""
        if self._cache is not None and self._cache[0] == t:
            return self._cache[1]
        if not t > self.t:
            return None
        try:
            d = preintegrated_delta(self.imu, self.calib.imu_time(self.t), self.calib.imu_time(t), self.calib,
                                    self.bias, params=self._params)
        except DatasetError as exc:
            log.debug("no IMU prediction at t=%.6f: %s", t, exc)
            return None
        self._cache = (t, d)
        return d

    def _imu_state(self) -> tuple[np.ndarray, np.ndarray]:
        T_world_imu = self.T_world_cam @ self._T_cam_imu
        return T_world_imu[:3, :3], T_world_imu[:3, 3]

    def predict(self, t: float) -> np.ndarray | None:
        """``T_world_cam`` predicted at time ``t`` (camera clock), or None (inactive, no IMU data)."""
        if not self.active:
            return None
        d = self._delta(float(t))
        if d is None:
            return None
        R_i, p_i = self._imu_state()
        R_j, p_j, _v_j = predict(R_i, p_i, self.v, d, self.g)
        T_world_imu = np.eye(4)
        T_world_imu[:3, :3], T_world_imu[:3, 3] = R_j, p_j
        self.n_predicted += 1
        return T_world_imu @ self.calib.T_imu_cam

    def velocity_at(self, t: float) -> np.ndarray | None:
        """The IMU velocity (world, m/s) at ``t``: the state's own at its time (after :meth:`update`),
        else the predicted ``v_j`` (an IMU-only frame); None without IMU data. Changes no state."""
        t = float(t)
        if t == self.t:
            return self.v.copy()
        d = self._delta(t)
        if d is None:
            return None
        R_i, p_i = self._imu_state()
        return predict(R_i, p_i, self.v, d, self.g)[2]

    def update(self, t: float, T_world_cam: np.ndarray) -> None:
        """Frame at ``t`` was tracked at ``T_world_cam``: the new state (module docstring)."""
        if not self.active:
            return
        t = float(t)
        d = self._delta(t)
        if d is not None:
            R_i, p_i = self._imu_state()
            T_world_imu_j = T_world_cam @ self._T_cam_imu
            dt = d.dt
            v_i = (T_world_imu_j[:3, 3] - p_i - 0.5 * self.g * dt * dt - R_i @ d.dp) / dt
            self.v = v_i + self.g * dt + R_i @ d.dv
        if t >= self.t:
            self.t = t
            self.T_world_cam = np.array(T_world_cam, float)
        self._cache = None

    def apply_correction(self, D: np.ndarray) -> None:
        """The map moved rigidly by ``D`` (local BA / loop correction of the newest keyframe): move the state."""
        self.T_world_cam = D @ self.T_world_cam
        self.v = D[:3, :3] @ self.v

    def stop(self, why: str) -> None:
        """Predict no more (the map segment the state lives in was left); the constant-velocity model takes over."""
        if self.active:
            log.warning("IMU prediction stopped: %s", why)
        self.active = False
