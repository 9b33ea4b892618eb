"""The IMU in localization (``vslam localize --sensor stereo-inertial ...``): prediction and bridging.

A visual-inertial map is gravity-aligned (z up) and metric, so the IMU's kinematics hold in its
world frame as they did while mapping. The localizer keeps one IMU state, that of the last
visually localized frame ``i`` (pose, velocity, biases), in a
:class:`vslam.frontend.imu_prediction.ImuPredictor`, and uses it three ways:

* **prediction**: the next frame ``j``'s pose from the deltas preintegrated from ``t_i`` to ``t_j``
  (Forster et al., T-RO 2017, eq. 33), in place of the constant-velocity model, once the velocity
  is known;
* **velocity**: when frame ``j`` is localized visually, the position equation solved for the
  velocity that the two localized poses imply, ``v_i = (p_j - p_i - 1/2 g dt^2 - R_i dp) / dt``,
  carried to ``j`` by ``v_j = v_i + g dt + R_i dv`` (:meth:`ImuPredictor.update`); it needs no
  earlier velocity, so one pair of localized frames is enough, after a relocalization too;
* **bridging**: a frame that neither tracking nor relocalization can localize (a dark or blurred
  frame) takes the IMU prediction as its pose (state ``imu``, counted as ``imu_only_frames``)
  while the last visually localized frame is at most ``frontend.tracking.imu_only_max_s`` back
  (the SLAM run's setting, 1 s by default); the state stays at that frame, so each bridged frame is
  predicted over the whole gap, and the next visual frame is matched from the IMU-predicted pose.

The biases are the map's (:func:`vslam.map.io_inertial.map_bias`: the median over its keyframes'
stored ``imu_bias``, a VI-BA's estimates; zero when the map stores none). The localizer does not
re-estimate them: over the short gaps the prediction spans, a bias error ``db`` moves a prediction
by ``1/2 db dt^2`` (0.1 m/s^2 over 0.5 s: 1.3 cm).
"""
from __future__ import annotations

import logging

import numpy as np

from vslam.frontend.imu_prediction import ImuPredictor
from vslam.inertial import ImuBias, ImuCalibration, ImuMeasurements

log = logging.getLogger(__name__)


class LocalizerImu:
    """The localizer's IMU state (module docstring).

    Args:
        imu, calib: the sequence's samples and calibration (``T_imu_cam`` of the localized camera).
        bias: the biases to preintegrate with (:func:`vslam.map.io_inertial.map_bias`).
        max_bridge_s: the longest gap since the last visually localized frame that IMU-only poses
            may span (0: never bridge).
    """

    def __init__(self, imu: ImuMeasurements, calib: ImuCalibration, bias: ImuBias, max_bridge_s: float) -> None:
        self.imu, self.calib, self.bias = imu, calib, bias
        self.max_bridge_s = float(max_bridge_s)
        self._pred: ImuPredictor | None = None
        self.velocity_known = False
        self.n_predicted = 0   # frames whose tracking started from the IMU prediction
        self.n_bridged = 0     # frames posed by the IMU alone

    def predict(self, t: float) -> np.ndarray | None:
        """``T_world_cam`` predicted at ``t`` once a velocity is known; None otherwise (no state
        yet, the IMU does not cover ``t``)."""
        if self._pred is None or not self.velocity_known:
            return None
        return self._pred.predict(t)

    def localized(self, t: float, T_world_cam: np.ndarray) -> None:
        """Frame at ``t`` was localized visually at ``T_world_cam``: the new state, its velocity from
        the previous state when that is recent (at most ``max_bridge_s`` back, or 0.5 s when bridging
        is off), else unknown until the next localized frame."""
        t = float(t)
        p = self._pred
        if p is not None and 0.0 < t - p.t <= max(self.max_bridge_s, 0.5):
            p.update(t, T_world_cam)  # velocity from the two poses (module docstring)
            self.velocity_known = True
            return
        self._pred = ImuPredictor(self.imu, self.calib, self.bias, t, T_world_cam, np.zeros(3))
        self.velocity_known = False

    def bridge(self, t: float) -> np.ndarray | None:
        """The IMU-only pose of a frame at ``t`` that vision could not localize, or None (no
        velocity, gap too long, no IMU data)."""
        p = self._pred
        if p is None or not self.velocity_known or not 0.0 < float(t) - p.t <= self.max_bridge_s:
            return None
        T = p.predict(t)
        if T is not None:
            self.n_bridged += 1
        return T

    def forget(self) -> None:
        """Lost beyond what the IMU bridges: the next localized frame starts a new state."""
        self._pred = None
        self.velocity_known = False
