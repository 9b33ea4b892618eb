"""Filter backend (``backend.type=ekf``): a constant-velocity pose EKF over the frontend's poses.

The filtering alternative to windowed optimization (Strasdat, Montiel & Davison, "Visual SLAM: why
filter?", IVC 2012, compare the two): every tracked frame's pose from the frontend is the measurement
``z_k`` of :class:`vslam.backend.ekf.PoseEKF`; the filter predicts with the constant-velocity model over
``dt`` = the timestamp difference, fuses ``z_k`` with a covariance from the pose's inlier count
(:func:`vslam.backend.ekf.pose_covariance_from_inliers`, the first-order ``sigma ~ e / (f sqrt(n))``
scaling, with the median depth of the reference keyframe's points), and the filtered pose replaces
the frame's output pose. Keyframes and map points are not touched: there is no local BA in this mode
(the map stays as the frontend built it) and tracking keeps its own motion model.

Lost frames get no pose (the filter only predicts through them); a measurement the Mahalanobis gate
rejects (``ekf.gate_chi2``) leaves the prediction as the output.

Example:
    >>> fb = FilterBackend(EKFConfig(), camera, system.map)                # doctest: +SKIP
    >>> T = fb.filter(frame.timestamp, T_world_cam_meas, n_inliers=250, ref_kf=3)  # doctest: +SKIP
"""
from __future__ import annotations

import logging

import numpy as np

from vslam.backend.config import EKFConfig
from vslam.backend.ekf import PoseEKF, pose_covariance_from_inliers
from vslam.geometry.camera import PinholeCamera
from vslam.map.map import Map

LOG = logging.getLogger(__name__)


class FilterBackend:
    """Feeds each tracked pose through a :class:`PoseEKF` (see the module docstring).

    Args:
        config: the EKF settings.
        camera: intrinsics (``fx`` scales the measurement covariance).
        map_: the map (the reference keyframe's points give the scene depth).
        reprojection_rmse_px: assumed pixel error of the frontend's inliers (None: the config's
            ``inlier_error_px``).
    """

    def __init__(self, config: EKFConfig | None, camera: PinholeCamera, map_: Map,
                 reprojection_rmse_px: float | None = None) -> None:
        self.config = config or EKFConfig()
        self.camera = camera
        self.map = map_
        self.rmse_px = float(self.config.inlier_error_px if reprojection_rmse_px is None else reprojection_rmse_px)
        self.ekf = PoseEKF(self.config)
        self._last_t: float | None = None
        self._depth_cache: dict[int, float] = {}
        self.n_updates = 0
        self.n_predict_only = 0
        self.correction_m: list[float] = []

    def _scene_depth(self, ref_kf: int | None) -> float:
        """Median depth of the reference keyframe's live points in its camera (1 m when unknown)."""
        if ref_kf is None:
            return 1.0
        if ref_kf in self._depth_cache:
            return self._depth_cache[ref_kf]
        kf = self.map.keyframes.get(ref_kf)
        depth = 1.0
        if kf is not None:
            ids = kf.observed_ids()
            ids = ids[self.map.points.alive[ids]]
            if len(ids):
                T_cw = kf.T_cam_world
                z = self.map.points.position[ids] @ T_cw[2, :3] + T_cw[2, 3]
                z = z[z > 0]
                if len(z):
                    depth = float(np.median(z))
        self._depth_cache[ref_kf] = depth
        return depth

    def filter(self, timestamp: float, T_world_cam: np.ndarray | None, n_inliers: int,
               ref_kf: int | None = None) -> np.ndarray | None:
        """One frame: predict to ``timestamp``, update with the measured pose; returns the filtered
        ``T_world_cam`` (None when the frame has no measurement)."""
        if self.ekf.initialized and self._last_t is not None:
            dt = float(timestamp) - self._last_t
            if dt > 0:
                self.ekf.predict(dt)
                self._last_t = float(timestamp)
        if T_world_cam is None:
            self.n_predict_only += 1
            return None
        cov = pose_covariance_from_inliers(max(int(n_inliers), 1), self.rmse_px, self.camera.fx,
                                           self._scene_depth(ref_kf), self.config.min_inlier_error_px)
        T = self.ekf.update(T_world_cam, cov)
        self._last_t = float(timestamp)
        self.n_updates += 1
        self.correction_m.append(float(np.linalg.norm(T[:3, 3] - T_world_cam[:3, 3])))
        return T

    def stats(self) -> dict:
        c = np.asarray(self.correction_m)
        return {
            "type": "ekf", "updates": self.n_updates, "predict_only": self.n_predict_only,
            "rejected_updates": self.ekf.rejected_updates,
            "mean_correction_m": round(float(c.mean()), 5) if len(c) else 0.0,
        }
