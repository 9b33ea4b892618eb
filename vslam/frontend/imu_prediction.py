"""The IMU's pose prediction for the next frame, replacing the constant-velocity model once the
IMU is initialized (ORB-SLAM3's ``Tracking::PredictStateIMU``), and the state it predicts from.

State: the last tracked frame's time ``t_i``, its IMU pose ``(R_i, p_i)`` (``T_world_imu =
T_world_cam @ T_cam_imu``), the IMU velocity ``v_i`` (world frame, m/s) and the biases. The world is
the gravity-aligned one (z up, gravity ``g = (0, 0, -9.81)``). Each tracked frame's velocity and
biases come from the inertial pose optimization (:meth:`ImuPredictor.optimize`,
:mod:`vslam.frontend.inertial_pose`); a keyframe's visual-inertial BA estimate replaces them
(:meth:`ImuPredictor.adopt_keyframe`). Only where that optimization cannot run (no keyframe state
yet, too few points) does :meth:`ImuPredictor.update` take the velocity from the tracked poses.

Prediction (Forster et al., "On-Manifold Preintegration for Real-Time Visual-Inertial Odometry",
T-RO 2017, eq. 33 solved for ``j``; the deltas ``dR, dv, dp`` preintegrated from ``t_i`` to
``t_j`` at the biases, :func:`vslam.inertial.preintegrated_delta`)::

    R_j = R_i dR
    v_j = v_i + g dt + R_i dv
    p_j = p_i + v_i dt + 1/2 g dt^2 + R_i dp

and ``T_world_cam_j = T_world_imu_j @ T_imu_cam``.

Velocity update without the optimization, once frame ``j`` is tracked at ``(R_j', p_j')``: the
position equation above gives the velocity at ``i`` that the two tracked positions imply,
``v_i' = (p_j' - p_i - 1/2 g dt^2 - R_i dp) / dt``, and the velocity equation carries it to ``j``:
``v_j = v_i' + g dt + R_i dv``
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
        use_optimized_pose: :meth:`optimize` gives the frame the optimized pose (True), or keeps the
            visual pose and takes only the velocity and biases (False). Measured on MH_01 80 frames
            (SE(3) ATE, velocity and biases from the optimization either way): stereo-inertial 0.00288
            / 0.00288 m, with frames 50-59 black 0.00279 / 0.00316; mono-inertial 0.00413 / 0.00280,
            black 0.0105 / 0.0042: the System takes it for stereo / RGB-D, not for monocular, whose
            frame poses (reprojections without depth) give way to the keyframe's velocity error
            carried over the interval; and only with the deterministic backend, whose VI-BA has
            estimated the newest keyframe's state by the next frame (``backend.mode=realtime``,
            stereo-inertial: 0.0042-0.0048 m with the optimized pose, 0.0028-0.0033 without, 0.0033
            before the optimization existed; parallel with the thread worker 0.0030 / 0.0030).
        anchors: ids of the keyframes whose stored state a visual-inertial BA estimated (a set the
            local mapper keeps up to date): :meth:`optimize` anchors on the newest of them, not on a
            keyframe whose state is tracking's own guess (held fixed, its error would pass to every
            frame after it; realtime mode, stereo-inertial on MH_01: SE(3) ATE 0.011 m anchored on
            the newest keyframe whatever its state, 0.003 m without the optimization). None: any
            keyframe with a state.
    """

    def __init__(self, imu: ImuMeasurements, calib: ImuCalibration, bias: ImuBias, timestamp: float,
                 T_world_cam: np.ndarray, velocity: np.ndarray, use_optimized_pose: bool = True,
                 anchors: set[int] | None = None) -> None:
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
        self.n_optimized = 0  # frames whose state came from the inertial pose optimization (optimize)
        self.use_optimized_pose = use_optimized_pose
        self.anchors = anchors
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

    def adopt_keyframe(self, timestamp: float, T_world_cam: np.ndarray, velocity: np.ndarray,
                       bias: np.ndarray) -> None:
        """A visual-inertial BA estimated the state of the keyframe at ``timestamp`` (``bias (6,)`` gyro
        then accelerometer): predict with its biases from now on; when the keyframe is the state's own
        frame (deterministic local mapping, right after it), take its pose and velocity too."""
        b = np.asarray(bias, float).reshape(6)
        self.bias = ImuBias(b[:3], b[3:])
        if float(timestamp) == self.t:
            self.T_world_cam = np.array(T_world_cam, float)
            self.v = np.asarray(velocity, float).reshape(3).copy()
        self._cache = None

    def set_state(self, timestamp: float, T_world_cam: np.ndarray, velocity: np.ndarray, bias: ImuBias) -> None:
        """The frame at ``timestamp`` has this optimized state (:mod:`vslam.frontend.inertial_pose`)."""
        self.t = float(timestamp)
        self.T_world_cam = np.array(T_world_cam, float)
        self.v = np.asarray(velocity, float).reshape(3).copy()
        self.bias = bias
        self._cache = None

    def optimize(self, t: float, T_world_cam: np.ndarray, keyframe, X_world: np.ndarray, uv: np.ndarray,
                 sigma: np.ndarray, u_right: np.ndarray | None, camera, bf: float | None) -> np.ndarray | None:
        """The frame at ``t``, tracked visually at ``T_world_cam`` with the inlier points ``X_world`` /
        ``uv`` / ``sigma`` / ``u_right``: optimize its pose, velocity and biases against the IMU motion
        since ``keyframe`` (its stored VI-BA state held fixed; :mod:`vslam.frontend.inertial_pose`) and
        make the result the state. Returns the optimized ``T_world_cam``, or None (no keyframe state,
        too few points, no IMU data: the caller keeps the visual pose and :meth:`update` runs)."""
        from vslam.frontend.inertial_pose import MIN_POINTS, InertialAnchor, optimize_inertial_pose
        from vslam.inertial import preintegrate

        v_k, b_k = keyframe.extra.get("imu_velocity"), keyframe.extra.get("imu_bias")
        if not self.active or v_k is None or b_k is None or len(X_world) < MIN_POINTS or not t > keyframe.timestamp:
            return None
        b_k = np.asarray(b_k, float)
        anchor = InertialAnchor(keyframe.timestamp, keyframe.T_world_cam, np.asarray(v_k, float),
                                ImuBias(b_k[:3], b_k[3:]))
        v0 = self.velocity_at(t)
        try:
            pim = preintegrate(self.imu, self.calib.imu_time(keyframe.timestamp), self.calib.imu_time(t),
                               self._params, anchor.bias)
        except DatasetError:
            return None
        res = optimize_inertial_pose(T_world_cam, self.v if v0 is None else v0, self.bias, anchor, pim, X_world, uv,
                                     sigma, u_right, (camera.fx, camera.fy, camera.cx, camera.cy), bf,
                                     self.calib.T_imu_cam)
        if not (np.all(np.isfinite(res.T_world_cam)) and np.all(np.isfinite(res.velocity))):
            return None
        self.n_optimized += 1
        T = res.T_world_cam if self.use_optimized_pose else np.asarray(T_world_cam, float)
        self.set_state(t, T, res.velocity, res.bias)
        return T

    def apply_correction(self, D: np.ndarray) -> None:
        """The map moved rigidly by ``D`` (local BA / loop correction of the newest keyframe): move the state."""
        self.T_world_cam = D @ self.T_world_cam
        self.v = D[:3, :3] @ self.v

    def stop(self, why: str) -> None:
        """Predict no more (the map segment the state lives in was left); the constant-velocity model takes over."""
        if self.active:
            log.warning("IMU prediction stopped: %s", why)
        self.active = False
