"""A frame's keypoints as an :class:`~vslam.frontend.observation.Observation`: detected
(``association=match``, and new KLT corners at keyframes) or carried from the previous frame by
KLT tracks (``association=track``), with depth from the depth image or the stereo pair."""
from __future__ import annotations

from typing import Any

import numpy as np

from vslam.datasets.frame import Frame
from vslam.features.config import FeatureConfig
from vslam.frontend.config import FrontendConfig
from vslam.frontend.observation import Observation, klt_track, sample_depth, stereo_pair_depth
from vslam.frontend.prepare import Detection
from vslam.geometry.camera import PinholeCamera, stereo_bf
from vslam.geometry.lie import inv_se3
from vslam.map.map import Map

BINARY_DETECTORS = ("orb", "gftt_orb", "brisk", "akaze")  # Hamming-distance descriptors


class Observer:
    """Keypoints, descriptors and depth of each frame (see the module docstring)."""

    def __init__(self, cfg: FrontendConfig, feature_cfg: FeatureConfig, camera: PinholeCamera, sensor: str,
                 map_: Map) -> None:
        from vslam.features.detect import create_detector

        self.cfg = cfg
        self.fcfg = feature_cfg
        self.camera = camera
        self.sensor = sensor
        self.map = map_
        self.detector = create_detector(feature_cfg)
        self.bf = stereo_bf(camera, sensor)
        self.prepared_feats: Any = None  # this frame's features detected ahead (Tracker.prepare), used once

    def observe(self, frame: Frame, gray: np.ndarray, T_world_pred: np.ndarray | None, prev: Observation | None,
                prev_gray: np.ndarray | None, predict_flow: bool) -> tuple[Observation, np.ndarray | None]:
        """``(observation, index into prev of each KLT track or None when detected)``; with
        ``predict_flow`` the KLT search starts at the prediction's projection of each map point."""
        cfg = self.cfg
        if not (cfg.association == "track" and prev is not None and prev_gray is not None and len(prev)):
            return self.detect(frame, gray), None
        init = self._predicted_uv(prev, T_world_pred) if T_world_pred is not None and predict_flow else None
        uv, ok = klt_track(prev_gray, gray, prev.uv, init, cfg.klt.window, cfg.klt.levels)
        if init is not None and ok.sum() < cfg.klt.retry_ratio * len(prev):  # a bad prediction: retry from zero flow
            uv2, ok2 = klt_track(prev_gray, gray, prev.uv, None, cfg.klt.window, cfg.klt.levels)
            if ok2.sum() > ok.sum():
                uv, ok = uv2, ok2
        klt_prev_idx = np.flatnonzero(ok)
        obs = prev.subset(klt_prev_idx)
        if obs.u_right is not None:  # carry the disparity (the stereo search starts from it)
            obs.u_right = uv[ok][:, 0] - (obs.uv[:, 0] - obs.u_right)
        obs.uv = uv[ok]
        obs.uv_undist = self.camera.undistort_points(obs.uv)
        # a point id dropped from the map stays dropped
        pid = obs.point_ids
        dead = (pid >= 0) & ~self.map.points.alive[np.clip(pid, 0, None)] if len(self.map.points) else pid >= 0
        obs.point_ids = np.where(dead, -1, pid)
        self.add_depth(frame, gray, obs)
        return obs, klt_prev_idx

    def _predicted_uv(self, prev: Observation, T_world_pred: np.ndarray) -> np.ndarray:
        """KLT start positions: mapped tracks at their map point's predicted projection, the
        others moved by the median predicted flow."""
        init = prev.uv.copy()
        has = prev.point_ids >= 0
        if has.any():
            X = self.map.points.position[prev.point_ids[has]]
            T_cw = inv_se3(T_world_pred)
            Xc = X @ T_cw[:3, :3].T + T_cw[:3, 3]
            front = Xc[:, 2] > 1e-3
            uvp = self.camera.project(np.where(front[:, None], Xc, 1.0))
            uvp = self.camera.distort_points(uvp)
            sub = init[has]
            sub[front] = uvp[front]
            init[has] = sub
            flow = np.median(init[has] - prev.uv[has], axis=0)
            init[~has] += flow
        return init

    def detect(self, frame: Frame, gray: np.ndarray, mask: np.ndarray | None = None) -> Observation:
        """Detect keypoints (within ``mask``), as a fresh observation with no map points."""
        feats, self.prepared_feats = (self.prepared_feats if mask is None else None), None  # from prepare()
        stereo = None
        if isinstance(feats, Detection):  # with the stereo depth found ahead
            feats, stereo = feats.features, feats.stereo
        if feats is None:
            feats = self.detector.detect(gray, mask) if mask is not None else self.detector.detect(gray)
        if self.cfg.association == "track" and len(feats) > self.cfg.klt.max_tracks:
            feats = feats.subset(np.unique(np.linspace(0, len(feats) - 1, self.cfg.klt.max_tracks).astype(np.int64)))
        n = len(feats)
        uv = np.asarray(feats.uv, dtype=float).reshape(-1, 2)
        obs = Observation(
            uv=uv,
            uv_undist=self.camera.undistort_points(uv),
            descriptors=None if self.cfg.association == "track" else feats.descriptors,
            octave=np.asarray(feats.octave, dtype=np.int32) if self.cfg.association == "match" else np.zeros(n, np.int32),
            depth=np.full(n, np.nan),
            point_ids=np.full(n, -1, dtype=np.int64),
            binary=feats.binary,
            scale_factor=feats.scale_factor,
            anchor_kf=np.full(n, -1, dtype=np.int64),
            anchor_idx=np.arange(n, dtype=np.int64),
        )
        if stereo is not None and self.sensor == "stereo" and len(stereo[0]) == n:
            obs.depth, obs.u_right = stereo  # what add_depth finds for a fresh detection (no disparity guess)
        else:
            self.add_depth(frame, gray, obs)
        return obs

    def add_depth(self, frame: Frame, gray: np.ndarray, obs: Observation) -> None:
        """Depth (and the virtual right coordinate ``u_right``) of each keypoint: sampled from the
        depth image (RGB-D) or matched along the row in the right image (stereo)."""
        from vslam.errors import DatasetError

        cfg = self.cfg
        n = len(obs)
        if self.sensor == "rgbd":
            if frame.depth is None:
                raise DatasetError(f"frame {frame.index} ({frame.path}) has no depth image but sensor is rgbd")
            obs.depth = sample_depth(frame.depth, obs.uv, cfg.depth.min_depth, cfg.depth.max_depth)
            obs.u_right = obs.uv_undist[:, 0] - self.bf / obs.depth
        elif self.sensor == "stereo":
            if frame.image_right is None:
                raise DatasetError(f"frame {frame.index} ({frame.path}) has no right image but sensor is stereo")
            d0 = None
            if obs.u_right is not None and len(obs.u_right) == n:
                d0 = obs.uv[:, 0] - obs.u_right  # last frame's disparity as the initial guess
            obs.depth, obs.u_right = stereo_pair_depth(frame, gray, obs.uv, self.camera, cfg.depth, d0)
        else:
            obs.depth = np.full(n, np.nan)
            obs.u_right = None
