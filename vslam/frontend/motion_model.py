"""Constant-velocity motion model: predict ``T_world_cur = T_world_prev @ T_prev_cur`` from the
last inter-frame motion (the prediction ORB-SLAM's TrackWithMotionModel uses)."""
from __future__ import annotations

import numpy as np

from vslam.geometry.lie import inv_se3  # the tracker's SE(3) inverse (no Sim(3) scale check)


class MotionModel:
    """Keeps the last relative motion ``T_prev_cur`` (per frame) and the last pose."""

    def __init__(self) -> None:
        self.T_world_last: np.ndarray | None = None
        self.T_last_cur: np.ndarray = np.eye(4)  # velocity: motion of the last frame step
        self.valid = False

    def reset(self, T_world_cam: np.ndarray | None = None) -> None:
        self.T_world_last = None if T_world_cam is None else T_world_cam.copy()
        self.T_last_cur = np.eye(4)
        self.valid = False

    def predict(self) -> np.ndarray | None:
        """The predicted ``T_world_cam`` of the next frame (None before the first pose)."""
        if self.T_world_last is None:
            return None
        return self.T_world_last @ self.T_last_cur

    def update(self, T_world_cam: np.ndarray) -> None:
        if self.T_world_last is not None:
            self.T_last_cur = inv_se3(self.T_world_last) @ T_world_cam
            self.valid = True
        self.T_world_last = T_world_cam.copy()
