"""Keyframe creation from a tracked frame (ORB-SLAM's CreateNewKeyFrame) and the keyframe decision.

A new keyframe gets, with ``association=track``, fresh corners away from the live tracks; with
depth (stereo / RGB-D) new map points from the keypoints' depths. Monocular keyframes carry what
local mapping needs to triangulate new points (``kf.extra``: ``triangulate``, and with KLT tracks
``anchor_kf`` / ``anchor_idx``, the keyframe and keypoint each track was born at); local mapping
(the keyframe listener) creates them, culls points and then the live observation takes the
keyframe's point ids.
"""
from __future__ import annotations

import logging
from typing import TYPE_CHECKING, Callable

import numpy as np

from vslam.datasets.frame import Frame
from vslam.features.config import FeatureConfig
from vslam.frontend.config import FrontendConfig
from vslam.frontend.keyframe_policy import need_keyframe
from vslam.frontend.observation import Observation, detect_mask
from vslam.frontend.observe import BINARY_DETECTORS, Observer
from vslam.geometry.camera import PinholeCamera
from vslam.map.keyframe import KeyFrame
from vslam.map.map import Map

if TYPE_CHECKING:
    from vslam.map.new_points import NewPointsParams

log = logging.getLogger(__name__)

_OBS_FIELDS = ("uv", "uv_undist", "descriptors", "octave", "depth", "point_ids", "u_right", "anchor_kf",
               "anchor_idx", "ref2d_idx")


class KeyframeMaker:
    """Makes keyframes from observations and inserts them into the map (see the module docstring)."""

    def __init__(self, cfg: FrontendConfig, feature_cfg: FeatureConfig, camera: PinholeCamera, sensor: str,
                 map_: Map, observer: Observer, on_keyframe: Callable[[KeyFrame], None] | None) -> None:
        self.cfg = cfg
        self.fcfg = feature_cfg
        self.camera = camera
        self.sensor = sensor
        self.map = map_
        self.observer = observer
        self.on_keyframe = on_keyframe
        self.scale_factor = feature_cfg.scale_factor
        self.max_level_scale = feature_cfg.scale_factor ** (feature_cfg.n_levels - 1)

    def make(self, frame_index: int, timestamp: float, T_world_cam: np.ndarray, obs: Observation,
             segment: int) -> KeyFrame:
        """A keyframe (not yet in the map) with copies of the observation's arrays."""
        return KeyFrame(
            id=self.map.next_keyframe_id(), frame_index=frame_index, timestamp=timestamp,
            T_world_cam=T_world_cam.copy(), uv=obs.uv.copy(), uv_undist=obs.uv_undist.copy(),
            descriptors=None if obs.descriptors is None else obs.descriptors.copy(),
            octave=obs.octave.copy(), depth=obs.depth.copy(), point_ids=obs.point_ids.copy(),
            segment=segment, u_right=None if obs.u_right is None else obs.u_right.copy(),
        )

    def insert(self, frame: Frame, gray: np.ndarray, obs: Observation, T_world_cam: np.ndarray, segment: int,
               new_points: bool = True) -> KeyFrame:
        """Make ``obs`` a keyframe, add it to the map and hand it to the keyframe listener (local
        mapping); afterwards ``obs.point_ids`` are the keyframe's (new points, remapped ids)."""
        cfg = self.cfg
        kf_id = self.map.next_keyframe_id()
        if cfg.association == "track":
            self._top_up_tracks(frame, gray, obs, kf_id)
        kf = self.make(frame.index, frame.timestamp, T_world_cam, obs, segment)
        if self.sensor != "mono":
            if new_points:
                self._points_from_depth(kf, obs)
        else:
            kf.extra["triangulate"] = new_points and (cfg.motion != "2d2d" or cfg.association == "track")
            if cfg.association == "track":
                kf.extra["anchor_kf"] = obs.anchor_kf.copy()
                kf.extra["anchor_idx"] = obs.anchor_idx.copy()
        self.map.add_keyframe(kf)
        if cfg.association == "match":
            # the keyframe's fresh observations become the points' descriptors
            has = kf.point_ids >= 0
            if kf.descriptors is not None and self.map.points.descriptor is not None:
                self.map.points.descriptor[kf.point_ids[has]] = kf.descriptors[has]
        if self.on_keyframe is not None:
            self.on_keyframe(kf)
        obs.point_ids = kf.point_ids.copy()  # local mapping's new points, ids remapped by its culling
        for key in ("triangulate", "anchor_kf", "anchor_idx"):  # consumed by the listener
            kf.extra.pop(key, None)
        return kf

    def _top_up_tracks(self, frame: Frame, gray: np.ndarray, obs: Observation, kf_id: int) -> None:
        """KLT tracks: new corners away from the existing ones, up to a bounded number of tracks."""
        cfg = self.cfg
        mask = detect_mask(gray.shape, obs.uv, max(cfg.klt.mask_min_radius_px, int(self.fcfg.cell_size // 2)))
        new = self.observer.detect(frame, gray, mask)
        room = max(min(cfg.klt.max_tracks, self.fcfg.n_features) - len(obs), 0)
        if len(new) > room:
            new = new.subset(np.unique(np.linspace(0, len(new) - 1, room).astype(np.int64)) if room else np.zeros(0, np.int64))
        new.anchor_kf = np.full(len(new), kf_id, dtype=np.int64)
        new.ref2d_idx = np.full(len(new), -1, dtype=np.int64)
        if obs.ref2d_idx is None:
            obs.ref2d_idx = np.full(len(obs), -1, dtype=np.int64)
        new.anchor_idx = np.arange(len(obs), len(obs) + len(new), dtype=np.int64)
        if obs.anchor_kf is None:
            obs.anchor_kf = np.full(len(obs), -1, np.int64)
            obs.anchor_idx = np.arange(len(obs), dtype=np.int64)
        merged = Observation.concat(obs, new)
        for name in _OBS_FIELDS:
            setattr(obs, name, getattr(merged, name))

    def _points_from_depth(self, kf: KeyFrame, obs: Observation) -> None:
        """Stereo / RGB-D: a map point at each unmatched keypoint with depth, nearest first (ORB-SLAM2
        CreateNewKeyFrame), at most ``local_map.max_points_per_keyframe``."""
        cand = np.flatnonzero((kf.point_ids < 0) & np.isfinite(kf.depth))
        if len(cand) == 0:
            return
        cand = cand[np.argsort(kf.depth[cand], kind="stable")][: self.cfg.local_map.max_points_per_keyframe]
        Xc = self.camera.backproject(kf.uv_undist[cand], kf.depth[cand])
        Xw = Xc @ kf.T_world_cam[:3, :3].T + kf.T_world_cam[:3, 3]
        desc = None if kf.descriptors is None else kf.descriptors[cand]
        ids = self.map.points.add(Xw, desc, kf.T_world_cam[:3, 3], kf.id,
                                  np.power(self.scale_factor, kf.octave[cand].astype(float)), self.max_level_scale)
        kf.point_ids[cand] = ids
        obs.point_ids[cand] = ids


def revisit_reference(map_: Map, local_kfs: list[int], point_ids: np.ndarray, last_kf: int | None,
                      min_age: int) -> int | None:
    """The old keyframe the frame is revisiting, or None: among the local map's keyframes the one
    observing most of the frame's tracked points (ORB-SLAM's UpdateLocalKeyFrames ``pKFmax``),
    when it is at least ``min_age`` keyframes older than the newest ``last_kf``.

    Tracking around that keyframe's covisible neighbours follows the old map along the revisited
    path, so a lap over a mapped place reuses its keyframes instead of adding new ones."""
    if min_age <= 0 or last_kf is None or len(local_kfs) < 2:
        return None
    ids = point_ids[point_ids >= 0]
    if len(ids) == 0:
        return None
    n = len(map_.points)
    mine = np.zeros(n, dtype=bool)
    mine[ids[ids < n]] = True
    best, best_n = None, 0
    for k in local_kfs:
        kf = map_.keyframes.get(k)
        if kf is None or kf.bad:
            continue
        shared = int(mine[kf.observed_ids()].sum())
        if shared > best_n or (shared == best_n and best is not None and k < best):
            best, best_n = k, shared
    if best is None or best > last_kf - min_age:
        return None
    return best


def decide_keyframe(cfg: FrontendConfig, sensor: str, obs: Observation, T_world_cam: np.ndarray, ref: KeyFrame | None,
                    frames_since_kf: int, n_ref_tracked: int, n_inliers: int, dense_wants: bool,
                    revisiting: bool = False, inertial: bool = False) -> bool:
    """ORB-SLAM's NeedNewKeyFrame (:func:`vslam.frontend.keyframe_policy.need_keyframe`) with the
    forcing reasons: KLT tracks running out, few close tracked points for depth sensors (ORB-SLAM2
    "close points"), a frame posed by dense alignment (``dense_wants``). ``n_ref_tracked``: map
    points the first frame after the reference keyframe tracked (it factors out the detector's
    frame-to-frame repeatability). ``revisiting`` (the reference is an old keyframe,
    :func:`revisit_reference`): elapsed frames alone (``keyframes.max_frames``) do not make a
    keyframe, as in ORB-SLAM where they only permit one when tracking is weak. ``inertial`` (an
    initialized IMU predicts the frames): depth sensors use ``keyframes.tracked_ratio_inertial``."""
    n_tracked = int((obs.point_ids >= 0).sum())
    force = False
    if cfg.association == "track":
        force = len(obs) < cfg.klt.min_tracks or n_tracked < cfg.klt.min_tracks * cfg.klt.min_mapped_ratio
    if sensor != "mono" and cfg.motion != "2d2d":
        close = np.isfinite(obs.depth) & (obs.point_ids >= 0)
        force |= close.sum() < cfg.keyframes.close_tracked_min \
            and (np.isfinite(obs.depth) & (obs.point_ids < 0)).sum() > cfg.keyframes.close_untracked_min
    force |= dense_wants
    moved = float(np.linalg.norm(T_world_cam[:3, 3] - ref.T_world_cam[:3, 3])) if ref is not None else 0.0
    ratio = cfg.keyframes.tracked_ratio_mono if sensor == "mono" else cfg.keyframes.tracked_ratio
    if inertial and sensor != "mono" and cfg.keyframes.tracked_ratio_inertial > 0:
        ratio = cfg.keyframes.tracked_ratio_inertial
    since = min(frames_since_kf, cfg.keyframes.max_frames - 1) if revisiting else frames_since_kf
    is_kf = need_keyframe(cfg, since, n_tracked, n_ref_tracked, n_inliers, moved, force, ratio)
    log.debug("%d inliers, %d/%d of the reference keyframe's points, force %s -> keyframe %s",
              n_inliers, n_tracked, n_ref_tracked, force, is_kf)
    return is_kf


def mapping_params(cfg: FrontendConfig, feature_cfg: FeatureConfig, K: np.ndarray) -> NewPointsParams:
    """The settings local mapping creates and culls points with (:mod:`vslam.map.new_points`),
    from the frontend's ``mono.*`` / ``local_map.*`` and the features' pyramid."""
    from vslam.map.new_points import NewPointsParams

    return NewPointsParams(
        K=K, scale_factor=feature_cfg.scale_factor,
        max_level_scale=feature_cfg.scale_factor ** (feature_cfg.n_levels - 1),
        binary=feature_cfg.detector in BINARY_DETECTORS, triangulation_keyframes=cfg.mono.triangulation_keyframes,
        match_ratio=cfg.mono.match_ratio, max_descriptor_distance=cfg.matching.max_descriptor_distance,
        max_reproj_sigmas=cfg.mono.max_reproj_sigmas, min_parallax_deg=cfg.mono.min_parallax_deg,
        cull_min_found_ratio=cfg.local_map.cull_min_found_ratio, max_map_points=cfg.local_map.max_map_points,
        local_keyframes=cfg.local_map.keyframes,
    )
