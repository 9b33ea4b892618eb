"""Starting a map segment: on the first frame with enough depth (stereo / RGB-D), or by the
monocular two-view initialization (:class:`vslam.frontend.initializer.MonoInitializer`, ORB-SLAM's
CreateInitialMapMonocular). A re-initialized segment starts at the last good pose; a monocular one
is scaled to the last known speed, so one Sim(3) aligns the whole run."""
from __future__ import annotations

import time

import numpy as np

from vslam.datasets.frame import Frame
from vslam.frontend.config import FrontendConfig
from vslam.frontend.initializer import MonoInitializer
from vslam.frontend.keyframes import KeyframeMaker
from vslam.frontend.motion_2d2d import TwoViewTracker
from vslam.frontend.observation import Observation
from vslam.frontend.observe import Observer
from vslam.frontend.state import TrackingState, TrackOutput
from vslam.geometry.lie import inv_se3
from vslam.geometry.pnp import pnp_ransac
from vslam.map.keyframe import KeyFrame
from vslam.map.map import Map
from vslam.map.matching import brute_force_match


class Bootstrap:
    """``initialize(frame, gray, obs) -> TrackOutput`` while ``state.status == 'initializing'``."""

    def __init__(self, cfg: FrontendConfig, sensor: str, map_: Map, state: TrackingState, observer: Observer,
                 keyframes: KeyframeMaker, two_view: TwoViewTracker, binary: bool, timers: dict[str, float]) -> None:
        self.cfg = cfg
        self.sensor = sensor
        self.map = map_
        self.state = state
        self.observer = observer
        self.keyframes = keyframes
        self.two_view = two_view
        self.binary = binary
        self.timers = timers
        self.K = observer.camera.K
        self.initializer = MonoInitializer(cfg, self.K)

    def reset(self) -> None:
        self.initializer.reset()

    def initialize(self, frame: Frame, gray: np.ndarray, obs: Observation) -> TrackOutput:
        if self.sensor == "mono":
            return self._initialize_mono(frame, gray, obs)
        st = self.state
        valid = np.isfinite(obs.depth)
        if valid.sum() < max(2 * self.cfg.tracking.min_inliers, self.cfg.init.min_depth_points):
            st.set_prev(obs, gray)
            return TrackOutput(None, "initializing", False, 0)
        st.segment += 1
        T_world_cam = st.origin()
        t0 = time.perf_counter()
        kf = self.keyframes.insert(frame, gray, obs, T_world_cam, st.segment)
        st.keyframe_inserted(kf.id)
        self.timers["mapping"] += time.perf_counter() - t0
        st.start(T_world_cam)
        st.set_prev(obs, gray)
        self.two_view.set_reference(obs, T_world_cam)
        return TrackOutput(T_world_cam, "ok", True, int(valid.sum()), st.ref_kf)

    def _initialize_mono(self, frame: Frame, gray: np.ndarray, obs: Observation) -> TrackOutput:
        cfg = self.cfg
        init = self.initializer
        if init.ref is None or init.attempts >= cfg.init.max_frames:
            self._set_reference(frame, gray, obs)
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
            self._set_reference(frame, gray, obs)
            return TrackOutput(None, "initializing", False, int(len(ref_idx)))
        t0 = time.perf_counter()
        res = init.try_initialize(ref_idx, obs, cur_idx)
        self.timers["pose"] += time.perf_counter() - t0
        if res is None:
            # keep the correspondences (not the image) to give this frame a pose once the map exists
            init.pending.append((frame.timestamp, ref_idx, obs.uv_undist[cur_idx]))
            self.state.set_prev(obs, gray)
            return TrackOutput(None, "initializing", False, int(len(ref_idx)))
        return self._create_mono_map(frame, gray, obs, res)

    def _create_mono_map(self, frame: Frame, gray: np.ndarray, cur: Observation, res) -> TrackOutput:
        """Two keyframes (the reference and this frame) and the triangulated points."""
        cfg, st, init = self.cfg, self.state, self.initializer
        # scale a re-initialized segment to the last known speed (keeps one Sim(3) for the run)
        T_cur_ref = res.T_cur_ref.copy()
        X_ref = res.X_ref.copy()
        gap = frame.index - init.ref_frame_index
        if st.speed_per_frame > 0 and st.T_world_last_good is not None:
            s = st.speed_per_frame * max(gap, 1) / max(np.linalg.norm(T_cur_ref[:3, 3]), 1e-9)
            T_cur_ref[:3, 3] *= s
            X_ref *= s
        st.segment += 1
        T_world_ref = st.origin()
        T_world_cur = T_world_ref @ inv_se3(T_cur_ref)
        X_world = X_ref @ T_world_ref[:3, :3].T + T_world_ref[:3, 3]
        t0 = time.perf_counter()
        kf0 = self.keyframes.make(init.ref_frame_index, init.ref_timestamp, T_world_ref, init.ref, st.segment)
        desc = None if cur.descriptors is None else cur.descriptors[res.cur_idx]
        pids = self.map.points.add(X_world, desc, T_world_ref[:3, 3], kf0.id,
                                   np.power(self.keyframes.scale_factor, init.ref.octave[res.ref_idx].astype(float)),
                                   self.keyframes.max_level_scale)
        kf0.point_ids[res.ref_idx] = pids
        self.map.add_keyframe(kf0)
        cur.point_ids[:] = -1
        cur.point_ids[res.cur_idx] = pids
        if cfg.association == "track":
            cur.anchor_kf = np.full(len(cur), kf0.id, dtype=np.int64)  # anchor_idx already indexes the reference
        st.last_kf = kf0.id
        kf = self.keyframes.insert(frame, gray, cur, T_world_cur, st.segment, new_points=cfg.association == "track")
        st.keyframe_inserted(kf.id)
        self.timers["mapping"] += time.perf_counter() - t0
        st.start(T_world_cur, T_world_prev=T_world_ref, gap=gap)
        Xc = X_world @ inv_se3(T_world_cur)[:3, :3].T + inv_se3(T_world_cur)[:3, 3]
        self.two_view.set_reference(cur, T_world_cur, Xc, res.cur_idx.copy())
        st.set_prev(cur, gray)
        backfill = [(init.ref_timestamp, T_world_ref)] + self._localize_pending(kf0)
        init.reset()
        return TrackOutput(T_world_cur, "ok", True, len(pids), st.ref_kf, backfill)

    def _localize_pending(self, kf0: KeyFrame) -> list[tuple[float, np.ndarray]]:
        """Poses of the frames seen between the reference and the initialization (PnP on the new map)."""
        out = []
        tr = self.cfg.tracking
        for ts, ref_idx, uv in self.initializer.pending:
            pid = kf0.point_ids[ref_idx]
            has = pid >= 0
            if has.sum() < tr.min_inliers:
                continue
            T_cw, m = pnp_ransac(self.map.points.position[pid[has]], uv[has], self.K, None, tr.pnp_reproj_px,
                                 tr.pnp_iterations)
            if T_cw is not None and m.sum() >= tr.min_inliers:
                out.append((ts, inv_se3(T_cw)))
        return out

    def _set_reference(self, frame: Frame, gray: np.ndarray, obs: Observation) -> None:
        if self.cfg.association == "track":
            # start fresh tracks at the reference so every track can be traced back to it
            obs = self.observer.detect(frame, gray)
        obs.anchor_idx = np.arange(len(obs), dtype=np.int64)
        obs.anchor_kf = np.full(len(obs), -1, dtype=np.int64)
        self.initializer.set_reference(obs, frame.index, frame.timestamp)
        self.state.set_prev(obs, gray)
