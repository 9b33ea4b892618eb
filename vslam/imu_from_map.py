"""An inertial session placed in a loaded visual-inertial map starts its IMU from the map.

``vslam run --map A`` with an inertial sensor first tries to place its frames in A by global
relocalization (:meth:`vslam.frontend.tracker.Tracker.start_in_map`). A is gravity-aligned (z up)
and metric, so once a frame is placed the session needs no initialization of its own (which a
monocular session only gets after 2 s of motion and 10 keyframes, longer than a short clip):

* gravity is the world's ``-z`` and the scale is A's (:meth:`InertialMapping.start_from_map`);
* the biases are A's keyframes' median (:func:`vslam.map.io_inertial.map_bias`), re-estimated by
  the visual-inertial local BAs of the session's own keyframes from then on;
* the velocity comes from the first two tracked poses: the position equation of the IMU kinematics
  solved for it (Forster et al. T-RO 2017, eq. 33; :meth:`ImuPredictor.update`), so the IMU predicts
  from the second tracked frame after the placement on.

The local VI-BA chains the session's own keyframes only (A's were taken with another recording's
IMU; :attr:`InertialLocalMapper.first_session_kf`), and no full VI-BA runs over A's keyframes.
A session whose frames cannot be placed starts its own segment and initializes its IMU there, as
before (:func:`vslam.api._continue_inertial`).
"""
from __future__ import annotations

import logging
from typing import Any

import numpy as np

from vslam.frontend.imu_prediction import ImuPredictor
from vslam.map.io_inertial import map_bias

log = logging.getLogger(__name__)


def tracker_predictor(system: Any, bias: Any, timestamp: float, T_world_cam: np.ndarray,
                      velocity: np.ndarray) -> ImuPredictor:
    """The tracker's :class:`ImuPredictor` of an inertial ``system`` from the state at ``timestamp``
    (after its own initialization or after a placement here): anchored on the keyframes a VI-BA
    estimated (the local mapper's ``estimated``; None: no visual-inertial local BA), and taking the
    optimized frame pose for depth sensors whose keyframe states a VI-BA gives in the same frame
    (the deterministic backend; see :class:`ImuPredictor`)."""
    anchors = getattr(system.local_mapper, "estimated", None)
    pose = not system.inertial.monocular and anchors is not None and system.local_mapper.config.mode == "deterministic"
    return ImuPredictor(system.inertial.imu, system.inertial.calib, bias, timestamp, T_world_cam, velocity,
                        use_optimized_pose=pose, anchors=anchors)


class MapImuStart:
    """Starts the IMU of ``system`` (an inertial :class:`vslam.system.System` continuing a loaded
    gravity-aligned map) from the map once a frame is placed in one of the loaded segments
    (module docstring). :meth:`step` runs on every tracked frame until it has."""

    def __init__(self, system: Any) -> None:
        self.system = system
        loaded = list(system.map.keyframes.values())
        self.loaded_segments = {k.segment for k in loaded}
        self.bias = map_bias(loaded)
        self._pending: ImuPredictor | None = None

    def applies(self) -> bool:
        """Whether the tracker works in a loaded segment it was placed in (else the session's IMU
        initializes itself, in its own segment)."""
        tracker = self.system.tracker
        return tracker.placed is not None and tracker.segment in self.loaded_segments

    def step(self, frame: Any, T_world_cam: np.ndarray) -> bool:
        """Frame ``frame`` (in a loaded segment, :meth:`applies`) was tracked at ``T_world_cam``: on
        the first such frame hold an IMU state there; on the next, take the velocity the two poses
        imply and hand the predictor to the tracker. True once the IMU runs."""
        s = self.system
        t = float(frame.timestamp)
        p = self._pending
        if p is None or not t > p.t:
            self._pending = tracker_predictor(s, self.bias, t, T_world_cam, np.zeros(3))
            return False
        p.update(t, T_world_cam)  # the velocity from the two tracked poses
        s.inertial.start_from_map(frame.index, t, self.bias)
        s.tracker.set_imu_predictor(p)
        if s.loop_closer is not None:
            s.loop_closer.imu_pending = False
        log.info("frame %d: IMU predicting from the loaded map's gravity (velocity %s m/s)",
                 frame.index, np.round(p.v, 3))
        return True
