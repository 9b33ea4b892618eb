"""Per-frame tracking: features -> association -> pose -> keyframe decision -> new map points.

One :class:`Tracker` serves the three sensors; the choices are

* association: ``match`` (guided descriptor matching of the projected local map, ORB-SLAM's
  TrackWithMotionModel + TrackLocalMap, Mur-Artal et al. 2015 sec. V) or ``track`` (KLT tracks
  carry their map point from frame to frame; new corners are detected at keyframes);
* motion: ``3d2d`` (PnP RANSAC + pose-only Gauss-Newton on reprojection and, for stereo/RGB-D,
  virtual-right-camera residuals), ``3d3d`` (RANSAC + weighted Kabsch of depth points onto map
  points), ``2d2d`` (essential matrix between consecutive frames, ``C_n = C_{n-1} T_n``, scaled by
  depth or, for monocular, by the relative scale of triangulated points).

A frame with too few inliers is *lost* (no pose); after ``tracking.max_lost_frames`` lost frames the tracker
re-initializes a new map segment anchored at the last good pose, so a run always continues.
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np
from scipy.spatial import cKDTree

from vslam.datasets.frame import Frame
from vslam.features.config import FeatureConfig
from vslam.frontend.config import FrontendConfig
from vslam.frontend.initializer import MonoInitializer
from vslam.frontend.keyframe_policy import need_keyframe
from vslam.map.matching import brute_force_match, guided_match, project_local_points
from vslam.frontend.motion_model import MotionModel
from vslam.frontend.prepare import FramePreparer
from vslam.frontend.observation import (
    Observation, detect_mask, klt_track, sample_depth, stereo_by_flow,
)
from vslam.geometry.align import align_ransac
from vslam.geometry.epipolar import essential_pose
from vslam.geometry.lie import inv_se3, make_T
from vslam.geometry.pnp import pnp_ransac, refine_pose
from vslam.geometry.triangulation import ray_parallax_deg, reprojection_error_depth, triangulate_dlt
from vslam.geometry.camera import PinholeCamera, stereo_bf
from vslam.map.keyframe import KeyFrame
from vslam.map.map import Map
from vslam.map.mappoint import unique_ids

log = logging.getLogger(__name__)


BINARY_DETECTORS = ("orb", "gftt_orb", "brisk", "akaze")


@dataclass
class TrackOutput:
    """What :meth:`Tracker.track` reports for one frame."""

    T_world_cam: np.ndarray | None
    state: str  # "ok" | "lost" | "initializing"
    is_keyframe: bool
    n_inliers: int
    ref_keyframe: int | None = None
    backfill: list[tuple[float, np.ndarray]] = field(default_factory=list)  # (timestamp, T_world_cam) of earlier frames


class Tracker:
    """Visual odometry against a local map; see the module docstring."""

    def __init__(
        self,
        cfg: FrontendConfig,
        feature_cfg: FeatureConfig,
        camera: PinholeCamera,
        sensor: str,
        map_: Map,
        on_keyframe: Callable[[KeyFrame], None] | None = None,
    ) -> None:
        from vslam.features.detect import create_detector

        cfg.check_sensor(sensor)
        if sensor == "stereo" and camera.baseline is None:
            from vslam.errors import CalibrationError

            raise CalibrationError("stereo tracking needs camera.baseline (rectified stereo calibration)")
        self.cfg = cfg
        self.fcfg = feature_cfg
        self.camera = camera
        self.sensor = sensor
        self.map = map_
        self.on_keyframe = on_keyframe
        self.detector = create_detector(feature_cfg)
        self.binary = feature_cfg.detector in BINARY_DETECTORS
        self.scale_factor = feature_cfg.scale_factor
        self.max_level_scale = feature_cfg.scale_factor ** (feature_cfg.n_levels - 1)
        self.K = camera.K
        self.bf = stereo_bf(camera, sensor)
        self.motion_model = MotionModel()
        self.initializer = MonoInitializer(cfg, self.K)
        self.state = "initializing"
        self.prev: Observation | None = None
        self.prev_gray: np.ndarray | None = None
        self.prev_klt_src: np.ndarray | None = None
        self.ref_kf: int | None = None
        self.last_kf: int | None = None
        self.frames_since_kf = 0
        self.segment = -1
        self.n_lost_run = 0
        self.T_world_last_good: np.ndarray | None = None
        self.speed_per_frame = 0.0
        self._local_ids: np.ndarray | None = None
        self._mono_X: tuple[np.ndarray, np.ndarray] | None = None  # (kp idx, X in that frame) for 2d2d mono
        self._pending_X: tuple[np.ndarray, np.ndarray] | None = None
        self._ref2d: Observation | None = None
        self._kf_ref_tracked: int | None = None
        self._T_world_ref2d: np.ndarray | None = None
        self.timers: dict[str, float] = {"features": 0.0, "association": 0.0, "pose": 0.0, "mapping": 0.0}
        self.n_frames = 0
        self.rng = np.random.default_rng(0)
        # set by the System when loop closing is on: Observation -> Relocalization | None
        self.relocalizer: Callable[..., Any] | None = None
        self.n_relocalized = 0
        self.n_depth_bridged = 0  # lost frames given a pose by depth ICP (RGB-D, see _bridge_with_depth)
        self._last_depth: tuple[np.ndarray, np.ndarray] | None = None  # (depth image, T_world_cam) of the last tracked frame
        self._last_gray: np.ndarray | None = None  # grey image of the last tracked frame (RGB-D)
        self.n_depth_refined = 0  # feature poses replaced by their dense RGB-D refinement (see _refine_with_depth)
        # RGB-D, frontend.dense.links: {kf_id: DenseLink} for keyframes posed by dense alignment to the
        # previous keyframe (vslam.backend.dense_links: local BA keeps that relative pose)
        self.dense_links: dict = {}
        self._dense_rel: np.ndarray | None = None  # this frame's T_prev_cur when dense alignment posed it
        self._last_tracked_kf: int | None = None  # keyframe id of the last tracked frame, None if not a keyframe
        # prepare() results by frame index: (frame, gray, Features or None); filled ahead of track()
        self._prepared: dict[int, tuple[Frame, np.ndarray, Any]] = {}
        self._prepared_feats = None
        self._preparer = self.preparer()
        self.timers.setdefault("prepare", 0.0)  # prepare() time (another thread's, when prefetching)

    # ================================================================== per frame
    def prepare(self, frame: Frame) -> None:
        """Work on ``frame`` that needs no tracking state (grayscale conversion and, with
        ``association=match``, feature detection), safe to run in another thread ahead of
        :meth:`track` (the runner's decoding thread calls it, see :func:`vslam.runner.run_sequence`).
        Uses its own detector instance; :meth:`track` picks the result up by frame identity."""
        t0 = time.perf_counter()
        gray, feats = self._preparer(frame)
        self.adopt_prepared(frame, gray, feats, time.perf_counter() - t0)

    def preparer(self) -> FramePreparer:
        """A picklable copy of what :meth:`prepare` runs, to run it in another process; hand its
        result to :meth:`adopt_prepared`."""
        return FramePreparer(self.fcfg, self.cfg.association)

    def adopt_prepared(self, frame: Frame, gray: np.ndarray, feats: Any, seconds: float = 0.0) -> None:
        """Take a :class:`FramePreparer` result for ``frame`` (computed elsewhere, e.g. by the
        runner's prefetch process); :meth:`track` uses it when it gets this very ``frame``."""
        if len(self._prepared) > 64:  # never consumed (frames dropped by the caller): keep memory flat
            self._prepared.clear()
        self._prepared[frame.index] = (frame, gray, feats)
        self.timers["prepare"] += seconds

    def track(self, frame: Frame) -> TrackOutput:
        self.n_frames += 1
        prep = self._prepared.pop(frame.index, None)
        if prep is not None and prep[0] is frame:
            gray, self._prepared_feats = prep[1], prep[2]
        else:
            gray, self._prepared_feats = frame.gray, None
        t0 = time.perf_counter()
        T_world_pred = self.motion_model.predict() if self.state != "initializing" else None
        obs, klt_prev_idx = self._observe(frame, gray, T_world_pred)
        self.timers["features"] += time.perf_counter() - t0

        if self.state == "initializing":
            out = self._initialize(frame, gray, obs, klt_prev_idx)
        else:
            out = self._track_initialized(frame, gray, obs, klt_prev_idx, T_world_pred)
        if out.T_world_cam is not None and self.sensor == "rgbd" and frame.depth is not None:
            if self._dense_rel is not None and out.is_keyframe and self._last_tracked_kf is not None:
                self._add_dense_link(frame, out.ref_keyframe, self._last_tracked_kf, self._dense_rel)
            self._last_tracked_kf = out.ref_keyframe if out.is_keyframe else None
            self._last_depth = (frame.depth, out.T_world_cam.copy())
            self._last_gray = gray
        self._dense_rel = None
        return out

    def _T_world_last_tracked(self) -> np.ndarray:
        """The current pose of the last tracked frame (the one of ``_last_depth``): its keyframe's
        (moved by local BA / loop corrections since) when it became one, else as tracked and corrected."""
        kf = self.map.keyframes.get(self._last_tracked_kf) if self._last_tracked_kf is not None else None
        if kf is not None:
            return kf.T_world_cam
        return self._last_depth[1] if self.T_world_last_good is None else self.T_world_last_good

    def _add_dense_link(self, frame: Frame, kf_id: int, prev_kf_id: int, T_prev_cur: np.ndarray) -> None:
        """Record that keyframe ``kf_id`` was posed by dense alignment to keyframe ``prev_kf_id``."""
        if not self.cfg.dense.links or kf_id is None or kf_id == prev_kf_id:
            return
        from vslam.map.dense_links import DenseLink, sample_depth_grid

        uv, z = sample_depth_grid(frame.depth, self.K, max_depth=min(self.cfg.depth.max_depth, self.cfg.dense.max_depth))
        if len(z):
            self.dense_links[kf_id] = DenseLink(kf_id, prev_kf_id, T_prev_cur.copy(), uv, z)

    # ------------------------------------------------------------------ features
    def _observe(self, frame: Frame, gray: np.ndarray, T_world_pred: np.ndarray | None):
        cfg = self.cfg
        klt_prev_idx = None
        if cfg.association == "track" and self.prev is not None and self.prev_gray is not None and len(self.prev):
            prev = self.prev
            init = None
            if T_world_pred is not None and self.motion_model.valid:
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
                    # move the others by the median predicted flow
                    flow = np.median(init[has] - prev.uv[has], axis=0)
                    init[~has] += flow
            uv, ok = klt_track(self.prev_gray, gray, prev.uv, init, cfg.klt.window, cfg.klt.levels)
            if init is not None and ok.sum() < self.cfg.klt.retry_ratio * len(prev):  # a bad prediction: retry from zero flow
                uv2, ok2 = klt_track(self.prev_gray, gray, prev.uv, None, cfg.klt.window, cfg.klt.levels)
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
            self._add_depth(frame, gray, obs)
        else:
            obs = self._detect(frame, gray)
        return obs, klt_prev_idx

    def _detect(self, frame: Frame, gray: np.ndarray, mask: np.ndarray | None = None) -> Observation:
        feats, self._prepared_feats = (self._prepared_feats if mask is None else None), None  # from prepare()
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
        self._add_depth(frame, gray, obs)
        return obs

    def _add_depth(self, frame: Frame, gray: np.ndarray, obs: Observation) -> None:
        cfg = self.cfg
        n = len(obs)
        if self.sensor == "rgbd":
            if frame.depth is None:
                from vslam.errors import DatasetError

                raise DatasetError(f"frame {frame.index} ({frame.path}) has no depth image but sensor is rgbd")
            obs.depth = sample_depth(frame.depth, obs.uv, cfg.depth.min_depth, cfg.depth.max_depth)
            obs.u_right = obs.uv_undist[:, 0] - self.bf / obs.depth
        elif self.sensor == "stereo":
            if frame.image_right is None:
                from vslam.errors import DatasetError

                raise DatasetError(f"frame {frame.index} ({frame.path}) has no right image but sensor is stereo")
            right = frame.image_right
            if right.ndim == 3:
                import cv2

                right = cv2.cvtColor(right, cv2.COLOR_BGR2GRAY)
            d0 = None
            if obs.u_right is not None and len(obs.u_right) == n:
                d0 = obs.uv[:, 0] - obs.u_right  # last frame's disparity as the initial guess
            obs.depth, obs.u_right = stereo_by_flow(
                gray, right, obs.uv, self.camera, cfg.depth.stereo_max_depth_baselines, cfg.depth.stereo_max_dy, cfg.depth.min_depth, d0,
            )
        else:
            obs.depth = np.full(n, np.nan)
            obs.u_right = None

    # ------------------------------------------------------------------ initialization
    def _T_world_origin(self) -> np.ndarray:
        return np.eye(4) if self.T_world_last_good is None else self.T_world_last_good.copy()

    def _initialize(self, frame: Frame, gray: np.ndarray, obs: Observation, klt_prev_idx) -> TrackOutput:
        if self.sensor != "mono":
            valid = np.isfinite(obs.depth)
            if valid.sum() < max(2 * self.cfg.tracking.min_inliers, self.cfg.init.min_depth_points):
                self._set_prev(obs, gray)
                return TrackOutput(None, "initializing", False, 0)
            self.segment += 1
            T_world_cam = self._T_world_origin()
            t0 = time.perf_counter()
            self._insert_keyframe(frame, gray, obs, T_world_cam)
            self.timers["mapping"] += time.perf_counter() - t0
            self._start_tracking(T_world_cam)
            self._set_prev(obs, gray)
            self._set_ref2d(obs, T_world_cam)
            return TrackOutput(T_world_cam, "ok", True, int(valid.sum()), self.ref_kf)
        return self._initialize_mono(frame, gray, obs)

    def _initialize_mono(self, frame: Frame, gray: np.ndarray, obs: Observation) -> TrackOutput:
        cfg = self.cfg
        init = self.initializer
        if init.ref is None or init.attempts >= cfg.init.max_frames:
            self._set_mono_reference(frame, gray, obs)
            return TrackOutput(None, "initializing", False, 0)
        t0 = time.perf_counter()
        if cfg.association == "match":
            ref_idx, cur_idx = brute_force_match(init.ref.descriptors, obs.descriptors, self.binary, ratio=cfg.init.match_ratio,
                                                 max_distance=cfg.init.max_descriptor_distance if self.binary else None)
        else:
            cur_idx = np.arange(len(obs))
            ref_idx = obs.anchor_idx.copy()
        self.timers["association"] += time.perf_counter() - t0
        if len(ref_idx) < cfg.init.min_matches:
            # too few correspondences left: this frame becomes the new reference
            self._set_mono_reference(frame, gray, obs)
            return TrackOutput(None, "initializing", False, int(len(ref_idx)))
        t0 = time.perf_counter()
        res = init.try_initialize(ref_idx, obs, cur_idx)
        self.timers["pose"] += time.perf_counter() - t0
        if res is None:
            # keep the correspondences (not the image) to give this frame a pose once the map exists
            init.pending.append((frame.timestamp, ref_idx, obs.uv_undist[cur_idx]))
            self._set_prev(obs, gray)
            return TrackOutput(None, "initializing", False, int(len(ref_idx)))
        # scale a re-initialized segment to the last known speed (keeps one Sim(3) for the run)
        T_cur_ref = res.T_cur_ref.copy()
        X_ref = res.X_ref.copy()
        gap = frame.index - init.ref_frame_index
        if self.speed_per_frame > 0 and self.T_world_last_good is not None:
            s = self.speed_per_frame * max(gap, 1) / max(np.linalg.norm(T_cur_ref[:3, 3]), 1e-9)
            T_cur_ref[:3, 3] *= s
            X_ref *= s
        self.segment += 1
        T_world_ref = self._T_world_origin()
        T_world_cur = T_world_ref @ inv_se3(T_cur_ref)
        X_world = X_ref @ T_world_ref[:3, :3].T + T_world_ref[:3, 3]
        t0 = time.perf_counter()
        ref = init.ref
        kf0 = self._make_keyframe(init.ref_frame_index, init.ref_timestamp, T_world_ref, ref)
        cur = obs
        desc = None if cur.descriptors is None else cur.descriptors[res.cur_idx]
        pids = self.map.points.add(X_world, desc, T_world_ref[:3, 3], kf0.id,
                                   np.power(self.scale_factor, ref.octave[res.ref_idx].astype(float)),
                                   self.max_level_scale)
        kf0.point_ids[res.ref_idx] = pids
        self.map.add_keyframe(kf0)
        cur.point_ids[:] = -1
        cur.point_ids[res.cur_idx] = pids
        if cfg.association == "track":
            cur.anchor_kf = np.full(len(cur), kf0.id, dtype=np.int64)  # anchor_idx already indexes the reference
        self.last_kf = kf0.id
        self._insert_keyframe(frame, gray, cur, T_world_cur, new_points=cfg.association == "track")
        self.timers["mapping"] += time.perf_counter() - t0
        self._start_tracking(T_world_cur, T_world_prev=T_world_ref, gap=gap)
        Xc = X_world @ inv_se3(T_world_cur)[:3, :3].T + inv_se3(T_world_cur)[:3, 3]
        self._set_ref2d(cur, T_world_cur, Xc, res.cur_idx.copy())
        self._set_prev(cur, gray)
        backfill = [(init.ref_timestamp, T_world_ref)] + self._localize_pending(kf0)
        init.reset()
        return TrackOutput(T_world_cur, "ok", True, len(pids), self.ref_kf, backfill)

    def _localize_pending(self, kf0: KeyFrame) -> list[tuple[float, np.ndarray]]:
        """Poses of the frames seen between the reference and the initialization (PnP on the new map)."""
        out = []
        for ts, ref_idx, uv in self.initializer.pending:
            pid = kf0.point_ids[ref_idx]
            has = pid >= 0
            if has.sum() < self.cfg.tracking.min_inliers:
                continue
            T_cw, m = pnp_ransac(self.map.points.position[pid[has]], uv[has], self.K, None, self.cfg.tracking.pnp_reproj_px,
                                 self.cfg.tracking.pnp_iterations)
            if T_cw is not None and m.sum() >= self.cfg.tracking.min_inliers:
                out.append((ts, inv_se3(T_cw)))
        return out

    def _set_mono_reference(self, frame: Frame, gray: np.ndarray, obs: Observation) -> None:
        if self.cfg.association == "track":
            # start fresh tracks at the reference so every track can be traced back to it
            obs = self._detect(frame, gray)
        obs.anchor_idx = np.arange(len(obs), dtype=np.int64)
        obs.anchor_kf = np.full(len(obs), -1, dtype=np.int64)
        self.initializer.set_reference(obs, frame.index, frame.timestamp)
        self._set_prev(obs, gray)

    def _start_tracking(self, T_world_cam: np.ndarray, T_world_prev: np.ndarray | None = None, gap: int = 1) -> None:
        self.state = "ok"
        self.n_lost_run = 0
        self.motion_model.reset(T_world_prev)
        if T_world_prev is not None:
            self.motion_model.update(T_world_cam)
            if gap > 1:  # per-frame velocity
                from vslam.geometry.lie import se3_exp, se3_log

                self.motion_model.T_last_cur = se3_exp(se3_log(self.motion_model.T_last_cur) / gap)
        else:
            self.motion_model.update(T_world_cam)
        self.T_world_last_good = T_world_cam.copy()

    def _set_prev(self, obs: Observation, gray: np.ndarray) -> None:
        self.prev = obs
        self.prev_gray = gray

    # ------------------------------------------------------------------ tracking
    def _local_point_ids(self) -> np.ndarray:
        if self._local_ids is None:
            kfs = self.map.local_keyframes(self.ref_kf, self.cfg.local_map.keyframes) if self.ref_kf is not None else []
            self._local_ids = self.map.local_point_ids(kfs)
        ids = self._local_ids
        return ids[self.map.points.alive[ids]]

    def _track_initialized(self, frame, gray, obs: Observation, klt_prev_idx, T_world_pred) -> TrackOutput:
        cfg = self.cfg
        if cfg.motion == "2d2d":
            T_world_cam, n_inl = self._pose_2d2d(obs, klt_prev_idx)
        else:
            T_world_cam, n_inl = self._pose_against_map(obs, T_world_pred, relocalize=self.state == "lost")
            if T_world_cam is None and self.relocalizer is not None:
                T_world_cam, n_inl = self._relocalize(obs)
        if T_world_cam is None:
            return self._lost(frame, gray, obs)
        if cfg.dense.refine and self.sensor == "rgbd" and cfg.motion != "2d2d" and n_inl < cfg.dense.refine_max_inliers:
            T_world_cam = self._refine_with_depth(frame, gray, T_world_cam)
        # ---------------------------------------------------------- keyframe?
        t0 = time.perf_counter()
        self.state = "ok"
        self.n_lost_run = 0
        self.frames_since_kf += 1
        ref = self.map.keyframes.get(self.ref_kf)
        # ORB-SLAM's NeedNewKeyFrame compares the map points tracked now with those tracked from the
        # reference keyframe; here the reference count is what the first frame after it tracked,
        # which factors out the detector's frame-to-frame repeatability
        n_tracked_ref = int((obs.point_ids >= 0).sum())
        if self.frames_since_kf == 1 or self._kf_ref_tracked is None:
            self._kf_ref_tracked = n_tracked_ref
        n_ref = self._kf_ref_tracked
        force = False
        if cfg.association == "track":
            force = len(obs) < cfg.klt.min_tracks or (obs.point_ids >= 0).sum() < cfg.klt.min_tracks * cfg.klt.min_mapped_ratio
        if self.sensor != "mono" and cfg.motion != "2d2d":
            # depth sensors: few close tracked points means the map is thinning (ORB-SLAM2 "close points")
            close = np.isfinite(obs.depth) & (obs.point_ids >= 0)
            force |= close.sum() < cfg.keyframes.close_tracked_min and (np.isfinite(obs.depth) & (obs.point_ids < 0)).sum() > cfg.keyframes.close_untracked_min
        if self._dense_rel is not None and cfg.dense.links and self._last_tracked_kf is not None:
            force = True  # posed by dense alignment to a keyframe: a keyframe keeps that link for local BA
        moved = float(np.linalg.norm(T_world_cam[:3, 3] - ref.T_world_cam[:3, 3])) if ref is not None else 0.0
        ratio = cfg.keyframes.tracked_ratio_mono if self.sensor == "mono" else cfg.keyframes.tracked_ratio
        is_kf = need_keyframe(cfg, self.frames_since_kf, n_tracked_ref, n_ref, n_inl, moved, force, ratio)
        log.debug("frame %d: %d inliers, %d/%d of the reference keyframe's points, force %s -> keyframe %s",
                  frame.index, n_inl, n_tracked_ref, n_ref, force, is_kf)
        if is_kf:
            self._insert_keyframe(frame, gray, obs, T_world_cam)
        self.timers["mapping"] += time.perf_counter() - t0
        # motion model
        if self.T_world_last_good is not None:
            self.speed_per_frame = float(np.linalg.norm(T_world_cam[:3, 3] - self.T_world_last_good[:3, 3]))
        self.motion_model.update(T_world_cam)
        self.T_world_last_good = T_world_cam.copy()
        self._set_prev(obs, gray)
        return TrackOutput(T_world_cam, "ok", is_kf, n_inl, self.ref_kf)

    def _relocalize(self, obs: Observation) -> tuple[np.ndarray | None, int]:
        """Tracking against the local map failed: find the pose among all keyframes of this map
        segment (bag-of-words candidates + PnP, :class:`vslam.loop.relocalization.Relocalizer`),
        then refine it against that keyframe's local map. First (no place recognition) against the
        reference and last keyframes, with the lower thresholds of ``Relocalizer.recover``: after a
        wide-baseline motion the constant-velocity prediction is useless but the map is not."""
        r = None
        if hasattr(self.relocalizer, "recover") and self.ref_kf is not None:
            r = self.relocalizer.recover(obs, [self.ref_kf, self.last_kf])
        if r is None:
            r = self.relocalizer(obs, segment=self.segment)
        if r is None:
            return None, 0
        self.ref_kf = r.keyframe_id
        self._local_ids = None
        T, n = self._pose_against_map(obs, r.T_world_cam, relocalize=True)
        if T is None:
            obs.point_ids[:] = -1
            obs.point_ids[r.kp_idx] = r.point_ids
            T, n = r.T_world_cam, r.n_inliers
        self.motion_model.reset(T)
        self.n_relocalized += 1
        log.info("relocalized against keyframe %d with %d inliers", r.keyframe_id, n)
        return T, n

    def _bridge_with_depth(self, frame, gray, obs) -> TrackOutput | None:
        """RGB-D, no pose from features: align this frame's depth image to the last tracked frame's
        (projective point-to-plane ICP from the motion prediction, :func:`vslam.frontend.depth_icp.align_depth`).
        If the depths agree, the frame becomes a keyframe of fresh depth points in the *same* map
        segment (a later loop closure can still correct the whole map) instead of a lost frame and,
        after ``tracking.max_lost_frames``, a new segment with an extrapolated origin."""
        if (not self.cfg.dense.icp_fallback or self.sensor != "rgbd" or self._last_depth is None
                or frame.depth is None or self.motion_model.T_world_last is None):
            return None
        t0 = time.perf_counter()
        T_world_prev = self._T_world_last_tracked()
        # from the motion prediction and from no motion (a turn the prediction did not foresee): the
        # better-agreeing alignment
        guesses = [inv_se3(T_world_prev) @ self.motion_model.predict(), np.eye(4)]
        T_prev_cur, agree = self._align_to_last(frame, gray, guesses, photometric=self.cfg.dense.icp_photometric)
        self.timers["pose"] += time.perf_counter() - t0
        if T_prev_cur is None:
            log.info("frame %d: depth ICP refused (%.2f of the depths agree)", frame.index, agree)
            return None
        T_world_cam = T_world_prev @ T_prev_cur
        self._dense_rel = T_prev_cur
        n = int(np.isfinite(obs.depth).sum())
        obs.point_ids[:] = -1
        t0 = time.perf_counter()
        self._insert_keyframe(frame, gray, obs, T_world_cam)
        self.timers["mapping"] += time.perf_counter() - t0
        self.state = "ok"
        self.n_lost_run = 0
        self.motion_model.update(T_world_cam)
        self.T_world_last_good = T_world_cam.copy()
        self._set_prev(obs, gray)
        self.n_depth_bridged += 1
        log.info("frame %d: no feature pose, bridged by depth ICP (%.2f of the depths agree)", frame.index, agree)
        return TrackOutput(T_world_cam, "ok", True, n, self.ref_kf)

    def _align_to_last(self, frame, gray, guesses: list[np.ndarray], photometric: bool) -> tuple[np.ndarray | None, float]:
        """``(T_prev_cur, depth agreement)`` of the best-agreeing dense alignment of this frame to the
        last tracked one (:func:`vslam.frontend.depth_icp.align_depth`) over the initial ``guesses``
        (``T_prev_cur``), or ``(None, best agreement)`` when none is accepted."""
        from vslam.frontend.depth_icp import align_depth

        depth_prev = self._last_depth[0]
        grays = (self._last_gray, gray) if photometric and self._last_gray is not None else (None, None)
        best, best_agree = None, 0.0
        for T_guess in guesses:
            T, agree = align_depth(depth_prev, frame.depth, self.K, T_guess, self.cfg.depth.min_depth,
                                   min(self.cfg.depth.max_depth, self.cfg.dense.max_depth), gray_prev=grays[0], gray_cur=grays[1],
                                   downsample=self.cfg.dense.refine_downsample if photometric else 1)
            if T is not None and (best is None or agree > best_agree):
                best, best_agree = T, agree
            elif best is None:
                best_agree = max(best_agree, agree)
        return best, best_agree

    def _refine_with_depth(self, frame, gray, T_world_cam: np.ndarray) -> np.ndarray:
        """RGB-D, a feature pose on few inliers (texture-poor views: the keypoints sit on object
        outlines, where the depth is ambiguous): refine the motion from the last tracked frame by
        dense alignment of the whole depth and grey images (point-to-plane ICP + photometric error,
        :func:`vslam.frontend.depth_icp.align_depth`), started at the feature pose. The refinement
        is kept when the depths agree at least as well as at the feature pose
        (:func:`vslam.frontend.depth_icp.depth_agreement`)."""
        if (self._last_depth is None or self._last_gray is None or frame.depth is None
                or self.T_world_last_good is None):
            return T_world_cam
        from vslam.frontend.depth_icp import depth_agreement

        t0 = time.perf_counter()
        depth_prev = self._last_depth[0]
        T_world_prev = self._T_world_last_tracked()
        T_guess = inv_se3(T_world_prev) @ T_world_cam
        agree0 = depth_agreement(np.nan_to_num(depth_prev), np.nan_to_num(frame.depth), self.K, T_guess)
        guesses = [T_guess]
        if agree0 < self.cfg.dense.doubtful_agreement:  # a doubtful feature pose: also from the motion prediction and from no motion
            guesses += [inv_se3(T_world_prev) @ self.motion_model.predict(), np.eye(4)]
        T_prev_cur, agree = self._align_to_last(frame, gray, guesses, photometric=True)
        self.timers["pose"] += time.perf_counter() - t0
        if T_prev_cur is None or agree < agree0:
            return T_world_cam
        self.n_depth_refined += 1
        self._dense_rel = T_prev_cur
        log.debug("frame %d: feature pose refined by dense RGB-D alignment (depth agreement %.2f)", frame.index, agree)
        return T_world_prev @ T_prev_cur

    def _lost(self, frame, gray, obs) -> TrackOutput:
        bridged = self._bridge_with_depth(frame, gray, obs)
        if bridged is not None:
            return bridged
        self.n_lost_run += 1
        self.state = "lost"
        log.info("frame %d lost (%d in a row)", frame.index, self.n_lost_run)
        if self.n_lost_run >= self.cfg.tracking.max_lost_frames:
            self._reinitialize()
            if self.sensor != "mono":  # depth sensors restart a map segment on this very frame
                obs.point_ids[:] = -1
                out = self._initialize(frame, gray, obs, None)
                if out.T_world_cam is not None:
                    return out
                self.state = "lost"
                return TrackOutput(None, "lost", False, 0)
        self._set_prev(obs, gray)
        # keep predicting from the last good pose: advance the motion model by one frame
        if self.motion_model.T_world_last is not None:
            self.motion_model.T_world_last = self.motion_model.T_world_last @ self.motion_model.T_last_cur
        return TrackOutput(None, "lost", False, 0)

    def _reinitialize(self) -> None:
        log.warning("tracking lost for %d frames: re-initializing a new map segment", self.n_lost_run)
        self.state = "initializing"
        self.initializer.reset()
        self.ref_kf = None
        self.last_kf = None
        self._local_ids = None
        self._mono_X = None
        self._ref2d = None
        if self.motion_model.T_world_last is not None:
            self.T_world_last_good = self.motion_model.T_world_last.copy()
        self.prev = None

    # ------------------------------------------------------------------ 3D-2D / 3D-3D against the map
    def _pose_against_map(self, obs: Observation, T_world_pred: np.ndarray | None, relocalize: bool):
        cfg = self.cfg
        pts = self.map.points
        T_cw_pred = inv_se3(T_world_pred) if T_world_pred is not None else None
        t0 = time.perf_counter()
        local_ids = self._local_point_ids()
        vis_ids = np.zeros(0, np.int64)
        if cfg.association == "match":
            obs.point_ids[:] = -1
            tree = cKDTree(obs.uv_undist) if len(obs) else None
            radius = cfg.matching.search_radius_lost_px if relocalize else cfg.matching.search_radius_px
            # first pass: the previous frame's map points (TrackWithMotionModel); the rest of the
            # local map follows at the refined pose
            first = np.zeros(0, np.int64)
            if not relocalize and self.prev is not None and len(self.prev):
                first = self.prev.point_ids[self.prev.point_ids >= 0]
                first = first[pts.alive[first]]
            m = np.zeros(0, np.int64)
            if len(first) >= cfg.tracking.enough_matches_factor * cfg.tracking.min_inliers:
                vis_ids, proj, _ = project_local_points(pts, first, T_cw_pred, self.camera, check_distance=False)
                m, k = self._guided(vis_ids, proj, obs, radius, tree)
            if len(m) < cfg.tracking.enough_matches_factor * cfg.tracking.min_inliers:
                vis_ids, proj, _ = project_local_points(pts, local_ids, T_cw_pred, self.camera)
                m, k = self._guided(vis_ids, proj, obs, radius, tree)
            if len(m) < cfg.tracking.enough_matches_factor * cfg.tracking.min_inliers and not relocalize:
                m, k = self._guided(vis_ids, proj, obs, cfg.matching.search_radius_lost_px, tree)
            if len(m) < cfg.tracking.min_inliers:
                m, k, vis_ids, T_cw_pred = self._match_without_prediction(obs, local_ids)
            obs.point_ids[k] = vis_ids[m]
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
            # second pass: the whole local map at the refined pose with a tight radius (TrackLocalMap)
            t1 = time.perf_counter()
            sel = np.flatnonzero(obs.point_ids >= 0)
            obs.point_ids[sel[~inl]] = -1  # keep the first pass's inliers
            first_ids = obs.point_ids.copy()
            inl = np.ones(int((first_ids >= 0).sum()), bool)
            kept = obs.point_ids[obs.point_ids >= 0]
            rest = unique_ids(len(pts), local_ids, first, exclude=kept)
            vis_ids, proj, _ = project_local_points(pts, rest, T_cw, self.camera)
            free = obs.point_ids < 0
            m, k = self._guided(vis_ids, proj, obs, max(cfg.matching.refine_radius_min_px, cfg.tracking.pnp_reproj_px * cfg.matching.refine_radius_factor), tree, free)
            obs.point_ids[k] = vis_ids[m]
            vis_ids = np.concatenate([kept, vis_ids])
            dt_assoc = time.perf_counter() - t1
            self.timers["association"] += dt_assoc
            t0 += dt_assoc  # not pose time
            T_cw2, inl2 = self._estimate(obs, T_cw, refine_only=True)
            if T_cw2 is not None and inl2.sum() >= inl.sum() * cfg.tracking.second_pass_keep_ratio:
                T_cw, inl = T_cw2, inl2
            else:  # the wider association did not hold: back to the first pass
                obs.point_ids = first_ids
        self.timers["pose"] += time.perf_counter() - t0
        if T_cw is None or inl.sum() < cfg.tracking.min_inliers:
            obs.point_ids[:] = -1 if cfg.association == "match" else obs.point_ids
            return None, int(0 if inl is None else inl.sum())
        sel = np.flatnonzero(obs.point_ids >= 0)
        bad = sel[~inl]
        obs.point_ids[bad] = -1
        if cfg.association == "match":
            pts.record(vis_ids, obs.point_ids[obs.point_ids >= 0])
        return inv_se3(T_cw), int(inl.sum())

    def _match_without_prediction(self, obs: Observation, local_ids: np.ndarray):
        """Descriptor matching of the whole local map (no pose prior); returns ``(map idx, keypoint idx,
        ids the map indices refer to, None)``."""
        empty = np.zeros(0, np.int64)
        if len(local_ids) == 0 or obs.descriptors is None or self.map.points.descriptor is None:
            return empty, empty, local_ids, None
        i1, i2 = brute_force_match(self.map.points.descriptor[local_ids], obs.descriptors, self.binary,
                                   ratio=self.cfg.matching.brute_force_ratio, max_distance=self.cfg.matching.max_descriptor_distance if self.binary else None)
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
            z = obs.depth[sel]
            has = np.isfinite(z)
            if has.sum() < cfg.tracking.min_inliers:
                return None, np.zeros(len(sel), bool)
            Xc = self.camera.backproject(uv[has], z[has])
            if self.sensor == "stereo":
                thr = np.maximum(cfg.tracking.align_inlier_m, cfg.tracking.align_stereo_disparity_px * z[has] ** 2 / self.bf)
            else:
                thr = cfg.tracking.align_inlier_m * np.maximum(1.0, z[has] ** 2)
            T_wc, m = align_ransac(Xc, Xw[has], thr, iterations=cfg.tracking.align_iterations if not refine_only else cfg.tracking.align_refine_iterations, rng=self.rng)
            inl = np.zeros(len(sel), bool)
            if T_wc is None:
                return None, inl
            inl[np.flatnonzero(has)[m]] = True
            return inv_se3(T_wc), inl
        # 3D-2D
        sigma = obs.sigma[sel]
        ur = None if obs.u_right is None else obs.u_right[sel]
        if T_cw_guess is not None and (refine_only or cfg.tracking.pose_from_prediction):
            # matches were gated around the prediction: robust pose optimization straight from it
            # (ORB-SLAM's TrackWithMotionModel); RANSAC only when that explains too few matches
            T_cw, inl = refine_pose(T_cw_guess, Xw, uv, self.K, sigma, ur, self.bf, rounds=2 if refine_only else 3)
            if refine_only or inl.sum() >= max(cfg.tracking.min_inliers, cfg.tracking.prediction_min_inlier_ratio * len(sel)):
                return T_cw, inl
        # with depth, a first-pass pose only places the second association pass (gate 4.5 px),
        # which a refinement with the depth residuals follows: one LM round on its inliers is
        # enough there (monocular KITTI 07 odometry drifts more with it: 1.16 vs < 1 m)
        T_cw, m = pnp_ransac(Xw, uv, self.K, T_cw_guess, cfg.tracking.pnp_reproj_px, cfg.tracking.pnp_iterations,
                             refine_rounds=1 if not final and self.sensor != "mono" else 2)
        if T_cw is None:
            return None, np.zeros(len(sel), bool)
        if not final:  # a refinement with all residuals follows the second association pass
            return T_cw, m
        T_cw, inl = refine_pose(T_cw, Xw, uv, self.K, sigma, ur, self.bf)
        return T_cw, inl

    # ------------------------------------------------------------------ 2D-2D
    def _set_ref2d(self, obs: Observation, T_world_cam: np.ndarray, X: np.ndarray | None = None,
                   X_idx: np.ndarray | None = None) -> None:
        """The 2D-2D reference frame: later frames are related to it by an essential matrix until the
        parallax suffices, then it advances (``C_n = C_ref T_n``)."""
        self._ref2d = obs
        self._T_world_ref2d = T_world_cam.copy()
        obs.ref2d_idx = np.arange(len(obs), dtype=np.int64)
        self._mono_X = None if X is None else (X_idx, X)

    def _pose_2d2d(self, obs: Observation, klt_prev_idx):
        cfg = self.cfg
        ref = getattr(self, "_ref2d", None)
        t0 = time.perf_counter()
        if ref is None or len(ref) < 8 or len(obs) < 8:
            return None, 0
        if cfg.association == "match":
            i1, i2 = brute_force_match(ref.descriptors, obs.descriptors, self.binary, ratio=cfg.two_view.match_ratio,
                                       max_distance=cfg.matching.max_descriptor_distance if self.binary else None)
            obs.point_ids[:] = -1
        else:
            r = obs.ref2d_idx if obs.ref2d_idx is not None else np.full(len(obs), -1)
            i2 = np.flatnonzero(r >= 0)
            i1 = r[i2]
        self.timers["association"] += time.perf_counter() - t0
        t0 = time.perf_counter()
        try:
            if len(i1) < cfg.tracking.min_inliers:
                return None, int(len(i1))
            x1, x2 = ref.uv_undist[i1], obs.uv_undist[i2]
            # with depth the rotation must come from E even at small parallax (a rotation-only fit would
            # absorb sideways translation); the translation then comes from the depths
            min_par = cfg.two_view.min_parallax_deg if self.sensor == "mono" else 0.0
            R, t, mask, status = essential_pose(x1, x2, self.K, cfg.tracking.essential_px, min_par)
            if R is None or mask.sum() < cfg.tracking.min_inliers:
                return None, int(mask.sum())
            advance = status == "ok"
            if self.sensor != "mono":
                z1, z2 = ref.depth[i1], obs.depth[i2]
                both = mask & np.isfinite(z1) & np.isfinite(z2)
                if both.sum() < 6:
                    return None, int(both.sum())
                Xp = self.camera.backproject(x1[both], z1[both])
                Xc = self.camera.backproject(x2[both], z2[both])
                diff = Xc - Xp @ R.T
                if status == "ok" and self.cfg.two_view.depth_scale_only:
                    t_m = float(np.median(diff @ t)) * t  # scale of the unit translation from depth
                else:  # the rotation from the images, the translation from the depths
                    t_m = np.median(diff, axis=0)
                T_world_cam = self._T_world_ref2d @ inv_se3(make_T(R, t_m))
            else:
                if status == "ok":
                    t_m = self._mono_scale(ref, obs, i1, i2, mask, R, t)
                    T_world_cam = self._T_world_ref2d @ inv_se3(make_T(R, t_m))
                else:
                    # too little parallax for a translation: rotation from the images, position from
                    # the constant-velocity model; the reference stays
                    T_world_cam = self.motion_model.predict()
                    T_world_cam[:3, :3] = self._T_world_ref2d[:3, :3] @ R.T
            if advance or len(i1) < cfg.two_view.advance_ratio * len(ref) \
                    or len(i1) < cfg.two_view.advance_min_inliers_factor * cfg.tracking.min_inliers:
                X = getattr(self, "_pending_X", None)
                self._set_ref2d(obs, T_world_cam, None if X is None else X[1], None if X is None else X[0])
            self._pending_X = None
            return T_world_cam, int(mask.sum())
        finally:
            self.timers["pose"] += time.perf_counter() - t0

    def _mono_scale(self, ref: Observation, obs: Observation, i1, i2, mask, R, t) -> np.ndarray:
        """Monocular 2D-2D translation with the relative scale: points triangulated from the previous
        pair and from this pair, both in the reference camera frame, compared by the median ratio of
        their distances (Scaramuzza & Fraundorfer, "Visual Odometry", RAM 2011, eq. (16))."""
        tv = self.cfg.two_view
        T_cur_ref_unit = make_T(R, t)
        idx = np.flatnonzero(mask)
        X = triangulate_dlt(np.eye(4), T_cur_ref_unit, self.K, ref.uv_undist[i1[idx]], obs.uv_undist[i2[idx]])
        e1, za = reprojection_error_depth(np.eye(4), self.K, X, ref.uv_undist[i1[idx]])
        e2, zb = reprojection_error_depth(T_cur_ref_unit, self.K, X, obs.uv_undist[i2[idx]])
        good = (za > 0) & (zb > 0) & (e1 < tv.max_reproj_px) & (e2 < tv.max_reproj_px) \
            & (ray_parallax_deg(np.eye(4), inv_se3(T_cur_ref_unit), X) > tv.min_point_parallax_deg)
        # fallback: the distance the motion model expects between the reference and this frame
        T_pred = self.motion_model.predict()
        s = float(np.linalg.norm(T_pred[:3, 3] - self._T_world_ref2d[:3, 3])) if T_pred is not None else 1.0
        if self._mono_X is not None and good.sum() >= tv.scale_min_points:
            old_idx, old_X = self._mono_X
            lookup = np.full(len(ref), -1, np.int64)
            lookup[old_idx] = np.arange(len(old_idx))
            j = lookup[i1[idx]]
            common = good & (j >= 0)
            if common.sum() >= tv.scale_min_points:
                ratio = np.linalg.norm(old_X[j[common]], axis=1) / np.linalg.norm(X[common], axis=1)
                s = float(np.median(ratio))
        if not np.isfinite(s) or s <= 0:
            s = 1.0
        Xs = X[good] * s
        self._pending_X = (i2[idx[good]], Xs @ R.T + s * t)  # in the current frame, for the next pair
        return s * t

    # ------------------------------------------------------------------ keyframes and new points
    def _make_keyframe(self, frame_index: int, timestamp: float, T_world_cam: np.ndarray, obs: Observation) -> KeyFrame:
        return KeyFrame(
            id=self.map.next_keyframe_id(), frame_index=frame_index, timestamp=timestamp,
            T_world_cam=T_world_cam.copy(), uv=obs.uv.copy(), uv_undist=obs.uv_undist.copy(),
            descriptors=None if obs.descriptors is None else obs.descriptors.copy(),
            octave=obs.octave.copy(), depth=obs.depth.copy(), point_ids=obs.point_ids.copy(),
            segment=self.segment, u_right=None if obs.u_right is None else obs.u_right.copy(),
        )

    def _insert_keyframe(self, frame: Frame, gray: np.ndarray, obs: Observation, T_world_cam: np.ndarray,
                         new_points: bool = True) -> KeyFrame:
        cfg = self.cfg
        kf_id = self.map.next_keyframe_id()
        if cfg.association == "track":
            # top up the tracks with new corners away from the existing ones
            mask = detect_mask(gray.shape, obs.uv, max(cfg.klt.mask_min_radius_px, int(self.fcfg.cell_size // 2)))
            new = self._detect(frame, gray, mask)
            room = max(min(cfg.klt.max_tracks, self.fcfg.n_features) - len(obs), 0)  # bounded number of tracks
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
            for name in ("uv", "uv_undist", "descriptors", "octave", "depth", "point_ids", "u_right",
                         "anchor_kf", "anchor_idx", "ref2d_idx"):
                setattr(obs, name, getattr(merged, name))
        kf = self._make_keyframe(frame.index, frame.timestamp, T_world_cam, obs)
        if new_points:
            if self.sensor != "mono":
                self._points_from_depth(kf, obs)
            elif cfg.motion != "2d2d" or cfg.association == "track":
                self._points_by_triangulation(kf, obs)
        self.map.add_keyframe(kf)
        if cfg.association == "match":
            # the keyframe's fresh observations become the points' descriptors
            has = kf.point_ids >= 0
            if kf.descriptors is not None and self.map.points.descriptor is not None:
                self.map.points.descriptor[kf.point_ids[has]] = kf.descriptors[has]
        self.map.cull_points(cfg.local_map.cull_min_found_ratio)
        local = self.map.local_keyframes(kf.id, cfg.local_map.keyframes)
        if self.map.points.n_alive > cfg.local_map.max_map_points:
            self.map.limit_points(cfg.local_map.max_map_points, local)
            # ids changed: remap the live observation
            kf_ids = kf.point_ids
            obs.point_ids = kf_ids.copy()
        self.ref_kf = kf.id
        self.last_kf = kf.id
        self._local_ids = None
        self.frames_since_kf = 0
        self._kf_ref_tracked = None
        if self.on_keyframe is not None:
            self.on_keyframe(kf)
        return kf

    def _points_from_depth(self, kf: KeyFrame, obs: Observation) -> None:
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

    def _points_by_triangulation(self, kf: KeyFrame, obs: Observation) -> None:
        """Monocular mapping: triangulate unmatched keypoints of the new keyframe with an earlier
        keyframe (descriptor matches with the last keyframe, or KLT tracks with their birth keyframe),
        keeping points in front of both views, with small reprojection error and enough parallax."""
        cfg = self.cfg
        if cfg.association == "match":
            # the previous keyframes of this segment, newest first
            olds = sorted((k for k in self.map.keyframes.values() if k.segment == kf.segment and k.id != kf.id),
                          key=lambda k: -k.id)[: cfg.mono.triangulation_keyframes]
            for old in olds:
                a = np.flatnonzero(old.point_ids < 0)
                b = np.flatnonzero(kf.point_ids < 0)
                if len(a) < 8 or len(b) < 8:
                    continue
                i1, i2 = brute_force_match(old.descriptors[a], kf.descriptors[b], self.binary, ratio=cfg.mono.match_ratio,
                                           max_distance=cfg.matching.max_descriptor_distance if self.binary else None)
                self._triangulate_pairs(old, a[i1], kf, b[i2], obs)
        else:
            anchors = obs.anchor_kf
            cand = np.flatnonzero((kf.point_ids < 0) & (anchors >= 0) & (anchors != kf.id))
            for a_id in np.unique(anchors[cand]):
                if a_id not in self.map.keyframes:
                    continue
                sel = cand[anchors[cand] == a_id]
                self._triangulate_pairs(self.map.keyframes[int(a_id)], obs.anchor_idx[sel], kf, sel, obs)

    def _triangulate_pairs(self, kf1: KeyFrame, idx1: np.ndarray, kf2: KeyFrame, idx2: np.ndarray, obs: Observation) -> None:
        if len(idx1) < 1:
            return
        ok1 = kf1.point_ids[idx1] < 0
        idx1, idx2 = idx1[ok1], idx2[ok1]
        if len(idx1) == 0:
            return
        T1, T2 = kf1.T_cam_world, kf2.T_cam_world
        x1, x2 = kf1.uv_undist[idx1], kf2.uv_undist[idx2]
        X = triangulate_dlt(T1, T2, self.K, x1, x2)
        e1, z1 = reprojection_error_depth(T1, self.K, X, x1)
        e2, z2 = reprojection_error_depth(T2, self.K, X, x2)
        s1 = np.power(self.scale_factor, kf1.octave[idx1].astype(float))
        s2 = np.power(self.scale_factor, kf2.octave[idx2].astype(float))
        par = ray_parallax_deg(kf1.T_world_cam, kf2.T_world_cam, X)
        good = np.all(np.isfinite(X), axis=1) & (z1 > 0) & (z2 > 0) & (e1 < self.cfg.mono.max_reproj_sigmas * s1) \
            & (e2 < self.cfg.mono.max_reproj_sigmas * s2) \
            & (par > self.cfg.mono.min_parallax_deg)
        if not good.any():
            return
        # a keypoint index may appear twice (KLT duplicates): keep the first
        _, first = np.unique(idx2[good], return_index=True)
        g = np.flatnonzero(good)[first]
        desc = None if kf2.descriptors is None else kf2.descriptors[idx2[g]]
        ids = self.map.points.add(X[g], desc, kf2.T_world_cam[:3, 3], kf2.id,
                                  np.power(self.scale_factor, kf2.octave[idx2[g]].astype(float)), self.max_level_scale)
        kf2.point_ids[idx2[g]] = ids
        obs.point_ids[idx2[g]] = ids
        kf1.point_ids[idx1[g]] = ids
        self.map.points.n_obs[ids] += 1
