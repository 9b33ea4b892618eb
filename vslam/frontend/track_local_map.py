"""Pose against the local map: associate the frame's keypoints with map points, then estimate the
pose (:mod:`vslam.frontend.motion_3d2d` or :mod:`vslam.frontend.motion_3d3d`).

With ``association=match`` two passes, after ORB-SLAM (Mur-Artal et al. 2015, sec. V-B/D): the
previous frame's points projected at the motion prediction (TrackWithMotionModel), widening to the
whole local map and to descriptor matching without a prior when that finds too few; then the whole
local map at the first-pass pose with a tight radius (TrackLocalMap). With ``association=track``
the KLT tracks already carry their map points.
"""
from __future__ import annotations

import time

import numpy as np
from scipy.spatial import cKDTree

from vslam.frontend.config import FrontendConfig
from vslam.frontend.motion_3d2d import pose_3d2d
from vslam.frontend.motion_3d3d import pose_3d3d
from vslam.frontend.observation import Observation
from vslam.geometry.camera import PinholeCamera, stereo_bf
from vslam.geometry.lie import inv_se3
from vslam.map.map import Map
from vslam.map.matching import brute_force_match, guided_match, project_local_points
from vslam.map.mappoint import unique_ids


class LocalMapTracker:
    """``track(obs, T_world_pred, local_ids, prev, relocalize) -> (T_world_cam or None, inliers)``;
    sets ``obs.point_ids`` to the inlier associations."""

    def __init__(self, cfg: FrontendConfig, camera: PinholeCamera, sensor: str, map_: Map, binary: bool,
                 timers: dict[str, float]) -> None:
        self.cfg = cfg
        self.camera = camera
        self.sensor = sensor
        self.map = map_
        self.binary = binary
        self.timers = timers
        self.bf = stereo_bf(camera, sensor)
        self.rng = np.random.default_rng(0)

    def track(self, obs: Observation, T_world_pred: np.ndarray | None, local_ids: np.ndarray,
              prev: Observation | None, relocalize: bool) -> tuple[np.ndarray | None, int]:
        cfg = self.cfg
        T_cw_pred = inv_se3(T_world_pred) if T_world_pred is not None else None
        t0 = time.perf_counter()
        vis_ids, first, tree = np.zeros(0, np.int64), np.zeros(0, np.int64), None
        if cfg.association == "match":
            # binary descriptors match through the grid kernel (map.matching_kernels): no KD-tree
            tree = cKDTree(obs.uv_undist) if len(obs) and not self.binary else None
            vis_ids, first, T_cw_pred = self._first_pass(obs, T_cw_pred, local_ids, prev, relocalize, tree)
        self.timers["association"] += time.perf_counter() - t0
        t0 = time.perf_counter()
        T_cw, inl = self._estimate(obs, T_cw_pred, final=cfg.association != "match")
        if (T_cw is None or inl.sum() < cfg.tracking.min_inliers) and cfg.association == "match" and T_cw_pred is not None:
            # the prediction misled the guided search (a fast or wide-baseline motion): relocalize
            # against the local map by descriptors alone
            t1 = time.perf_counter()
            obs.point_ids[:] = -1
            m, k, vis_ids, T_cw_pred = self._match_without_prediction(obs, local_ids)
            obs.point_ids[k] = vis_ids[m]
            self.timers["association"] += time.perf_counter() - t1
            T_cw, inl = self._estimate(obs, None, final=False)
        if T_cw is not None and cfg.association == "match":
            T_cw, inl, vis_ids, dt_assoc = self._second_pass(obs, T_cw, inl, local_ids, first, tree)
            self.timers["association"] += dt_assoc
            t0 += dt_assoc  # not pose time
        self.timers["pose"] += time.perf_counter() - t0
        if T_cw is None or inl.sum() < cfg.tracking.min_inliers:
            obs.point_ids[:] = -1 if cfg.association == "match" else obs.point_ids
            return None, int(0 if inl is None else inl.sum())
        sel = np.flatnonzero(obs.point_ids >= 0)
        obs.point_ids[sel[~inl]] = -1
        if cfg.association == "match":
            self.map.points.record(vis_ids, obs.point_ids[obs.point_ids >= 0])
        return inv_se3(T_cw), int(inl.sum())

    def _first_pass(self, obs, T_cw_pred, local_ids, prev, relocalize, tree):
        """Guided matching at the prediction: the previous frame's map points, else the local map,
        else a wider radius, else descriptors alone. Returns ``(ids the associations index,
        the previous frame's ids, T_cw_pred or None when matched without it)``."""
        cfg = self.cfg
        pts = self.map.points
        obs.point_ids[:] = -1
        radius = cfg.matching.search_radius_lost_px if relocalize else cfg.matching.search_radius_px
        enough = cfg.tracking.enough_matches_factor * cfg.tracking.min_inliers
        vis_ids = np.zeros(0, np.int64)
        first = np.zeros(0, np.int64)
        if not relocalize and prev is not None and len(prev):
            first = prev.point_ids[prev.point_ids >= 0]
            first = first[pts.alive[first]]
        m = k = np.zeros(0, np.int64)
        if len(first) >= enough:
            vis_ids, proj, _ = project_local_points(pts, first, T_cw_pred, self.camera, check_distance=False)
            m, k = self._guided(vis_ids, proj, obs, radius, tree)
        if len(m) < enough:
            vis_ids, proj, _ = project_local_points(pts, local_ids, T_cw_pred, self.camera)
            m, k = self._guided(vis_ids, proj, obs, radius, tree)
        if len(m) < enough and not relocalize:
            m, k = self._guided(vis_ids, proj, obs, cfg.matching.search_radius_lost_px, tree)
        if len(m) < cfg.tracking.min_inliers:
            m, k, vis_ids, T_cw_pred = self._match_without_prediction(obs, local_ids)
        obs.point_ids[k] = vis_ids[m]
        return vis_ids, first, T_cw_pred

    def _second_pass(self, obs, T_cw, inl, local_ids, first, tree):
        """The whole local map at the first-pass pose with a tight radius (TrackLocalMap), then a
        robust refinement; back to the first pass when the wider association does not hold.
        Returns ``(T_cw, inlier mask, ids the associations index, seconds spent associating)``."""
        t1 = time.perf_counter()
        cfg = self.cfg
        pts = self.map.points
        sel = np.flatnonzero(obs.point_ids >= 0)
        obs.point_ids[sel[~inl]] = -1  # keep the first pass's inliers
        first_ids = obs.point_ids.copy()
        inl = np.ones(int((first_ids >= 0).sum()), bool)
        kept = obs.point_ids[obs.point_ids >= 0]
        rest = unique_ids(len(pts), local_ids, first, exclude=kept)
        vis_ids, proj, _ = project_local_points(pts, rest, T_cw, self.camera)
        free = obs.point_ids < 0
        radius = max(cfg.matching.refine_radius_min_px, cfg.tracking.pnp_reproj_px * cfg.matching.refine_radius_factor)
        m, k = self._guided(vis_ids, proj, obs, radius, tree, free)
        obs.point_ids[k] = vis_ids[m]
        vis_ids = np.concatenate([kept, vis_ids])
        dt_assoc = time.perf_counter() - t1
        T_cw2, inl2 = self._estimate(obs, T_cw, refine_only=True)
        if T_cw2 is not None and inl2.sum() >= inl.sum() * cfg.tracking.second_pass_keep_ratio:
            return T_cw2, inl2, vis_ids, dt_assoc
        obs.point_ids = first_ids  # the wider association did not hold: back to the first pass
        return T_cw, inl, vis_ids, dt_assoc

    def _match_without_prediction(self, obs: Observation, local_ids: np.ndarray):
        """Descriptor matching of the whole local map (no pose prior); returns ``(map idx, keypoint idx,
        ids the map indices refer to, None)``."""
        empty = np.zeros(0, np.int64)
        if len(local_ids) == 0 or obs.descriptors is None or self.map.points.descriptor is None:
            return empty, empty, local_ids, None
        i1, i2 = brute_force_match(self.map.points.descriptor[local_ids], obs.descriptors, self.binary,
                                   ratio=self.cfg.matching.brute_force_ratio,
                                   max_distance=self.cfg.matching.max_descriptor_distance if self.binary else None)
        return i1, i2, local_ids, None

    def _guided(self, vis_ids, proj, obs: Observation, radius: float, tree, free: np.ndarray | None = None):
        if len(vis_ids) == 0 or obs.descriptors is None or len(obs) == 0:
            return np.zeros(0, np.int64), np.zeros(0, np.int64)
        m, k, _ = guided_match(
            proj, self.map.points.descriptor[vis_ids], obs.uv_undist, obs.descriptors, radius, self.binary,
            self.cfg.matching.max_descriptor_distance if self.binary else None, self.cfg.matching.match_ratio, kp_tree=tree,
            kp_free=free,
        )
        return m, k

    def _estimate(self, obs: Observation, T_cw_guess: np.ndarray | None, refine_only: bool = False,
                  final: bool = True):
        """Pose from the associated points of ``obs``; returns ``(T_cam_world, inlier mask over
        the associated points in index order)``."""
        cfg = self.cfg
        sel = np.flatnonzero(obs.point_ids >= 0)
        if len(sel) < cfg.tracking.min_inliers:
            return None, np.zeros(len(sel), bool)
        Xw = self.map.points.position[obs.point_ids[sel]]
        uv = obs.uv_undist[sel]
        if cfg.motion == "3d3d":
            return pose_3d3d(cfg, self.camera, self.sensor, self.bf, Xw, uv, obs.depth[sel], self.rng, refine_only)
        ur = None if obs.u_right is None else obs.u_right[sel]
        return pose_3d2d(cfg, self.camera.K, self.bf, self.sensor, Xw, uv, obs.sigma[sel], ur, T_cw_guess,
                         refine_only, final)
