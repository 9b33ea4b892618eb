"""Per-frame tracking: features -> association -> pose -> keyframe decision.

One :class:`Tracker` serves the three sensors; the choices are

* association: ``match`` (guided descriptor matching of the projected local map, ORB-SLAM's
  TrackWithMotionModel + TrackLocalMap, Mur-Artal et al. 2015 sec. V) or ``track`` (KLT tracks
  carry their map point from frame to frame; new corners are detected at keyframes);
* motion: ``3d2d`` (:mod:`vslam.frontend.motion_3d2d`), ``3d3d``
  (:mod:`vslam.frontend.motion_3d3d`), ``2d2d`` (:mod:`vslam.frontend.motion_2d2d`).

The pieces: :mod:`~vslam.frontend.observe` (keypoints and depth), :mod:`~vslam.frontend.bootstrap`
(a map segment's first keyframes), :mod:`~vslam.frontend.track_local_map` (pose against the local
map), :mod:`~vslam.frontend.dense_refine` (RGB-D dense alignment), :mod:`~vslam.frontend.keyframes`
(keyframe decision and creation), :mod:`~vslam.frontend.state` (what is kept between frames).
New monocular points and point culling belong to local mapping (:mod:`vslam.map.new_points`,
run by the keyframe listener).

A frame with too few inliers is *lost* (no pose); after ``tracking.max_lost_frames`` lost frames
(``max_lost_frames_mono`` for monocular, which is relocalized for longer first) the
tracker re-initializes a new map segment anchored at the last good pose, so a run always continues.
Corrections of the map (local BA, loop closing) reach the tracker through :meth:`Tracker.apply_correction`.

Continuing a loaded map (:meth:`Tracker.start_in_map`): the tracker starts *placing* instead of
initializing; each frame is relocalized globally (bag of words + PnP, any segment of the map) until
one succeeds, and tracking goes on in the segment of the keyframe it was placed against. After
``max_frames_to_place`` frames without a place, a new segment is bootstrapped (as after a loss).
"""
from __future__ import annotations

import logging
import time
from typing import Any, Callable

import numpy as np

from vslam.datasets.frame import Frame
from vslam.features.config import FeatureConfig
from vslam.frontend.bootstrap import Bootstrap
from vslam.frontend.config import FrontendConfig
from vslam.frontend.dense_refine import DenseTracker
from vslam.frontend.keyframes import KeyframeMaker, decide_keyframe, revisit_reference
from vslam.frontend.motion_2d2d import TwoViewTracker
from vslam.frontend.motion_model import MotionModel
from vslam.frontend.observation import Observation
from vslam.frontend.observe import BINARY_DETECTORS, Observer
from vslam.frontend.prepare import FramePreparer
from vslam.frontend.state import TrackingState, TrackOutput
from vslam.frontend.track_local_map import LocalMapTracker
from vslam.geometry.camera import PinholeCamera
from vslam.map.keyframe import KeyFrame
from vslam.map.map import Map
from vslam.map.segment_merge import move_pose, similarity_scale

__all__ = ["BINARY_DETECTORS", "TrackOutput", "Tracker"]

log = logging.getLogger(__name__)


class Tracker:
    """Visual odometry against a local map; see the module docstring.

    Args:
        cfg, feature_cfg: the frontend's and the features' settings.
        camera: intrinsics (``baseline`` for stereo); sensor: ``mono``, ``stereo`` or ``rgbd``.
        map_: the shared map. on_keyframe: called with each new keyframe (local mapping).
        relocalizer: ``relocalizer(obs, segment=...) -> Relocalization | None`` used when lost
            (:class:`vslam.loop.relocalization.Relocalizer`), or set later with :meth:`set_relocalizer`.
    """

    def __init__(self, cfg: FrontendConfig, feature_cfg: FeatureConfig, camera: PinholeCamera, sensor: str,
                 map_: Map, on_keyframe: Callable[[KeyFrame], None] | None = None,
                 relocalizer: Callable[..., Any] | None = None) -> None:
        cfg.check_sensor(sensor)
        if sensor == "stereo" and camera.baseline is None:
            from vslam.errors import CalibrationError

            raise CalibrationError("stereo tracking needs camera.baseline (rectified stereo calibration)")
        self.cfg = cfg
        self.fcfg = feature_cfg
        self.camera = camera
        self.sensor = sensor
        self.map = map_
        # the monocular variants of two settings (0: the setting for every sensor)
        mono = sensor == "mono"
        self.n_local_keyframes = (mono and cfg.local_map.keyframes_mono) or cfg.local_map.keyframes
        self.max_lost_frames = (mono and cfg.tracking.max_lost_frames_mono) or cfg.tracking.max_lost_frames
        self.timers: dict[str, float] = {"features": 0.0, "association": 0.0, "pose": 0.0, "mapping": 0.0,
                                         "prepare": 0.0}  # prepare: another thread's, when prefetching
        self.state = TrackingState()
        self.n_frames = 0
        self.n_relocalized = 0
        self._relocalizer = relocalizer
        self._place_left = 0  # frames left to place in a loaded map (status "placing")
        self.placed: tuple[int, int, int] | None = None  # first frame placed in a loaded map: (frame, keyframe, inliers)
        binary = feature_cfg.detector in BINARY_DETECTORS
        self.observer = Observer(cfg, feature_cfg, camera, sensor, map_)
        self.keyframes = KeyframeMaker(cfg, feature_cfg, camera, sensor, map_, self.observer, on_keyframe)
        self.local_map = LocalMapTracker(cfg, camera, sensor, map_, binary, self.timers)
        self.two_view = TwoViewTracker(cfg, camera, sensor, binary, self.timers)
        self.dense = DenseTracker(cfg, camera.K, map_, self.timers)
        self.bootstrap = Bootstrap(cfg, sensor, map_, self.state, self.observer, self.keyframes, self.two_view,
                                   binary, self.timers)
        # prepare() results by frame index: (frame, gray, Features or None); filled ahead of track()
        self._prepared: dict[int, tuple[Frame, np.ndarray, Any]] = {}
        self._preparer = self.preparer()
        # inertial sensors, once the IMU is initialized: the pose prediction (System.set_imu_predictor)
        self.imu_predictor: Any = None
        self._imu_pred: np.ndarray | None = None  # this frame's IMU prediction (None: none)
        self.n_imu_only = 0  # frames posed by the IMU alone (vision failed; _imu_only)

    # ================================================================== public surface
    def set_relocalizer(self, relocalizer: Callable[..., Any] | None) -> None:
        """Use ``relocalizer(obs, segment=...)`` (and its ``recover``) when tracking is lost."""
        self._relocalizer = relocalizer

    def apply_correction(self, T_world_new_from_old: np.ndarray) -> None:
        """The map moved under the tracker (local BA or a loop correction moved the newest keyframe
        by ``D = T_world_kf_after @ inv(T_world_kf_before)``): move the last poses with it."""
        self.state.apply_correction(T_world_new_from_old)
        if self.imu_predictor is not None:
            self.imu_predictor.apply_correction(T_world_new_from_old)

    def set_imu_predictor(self, predictor: Any) -> None:
        """Predict each next frame with ``predictor.predict(timestamp)`` (an
        :class:`~vslam.frontend.imu_prediction.ImuPredictor`) instead of the constant-velocity model,
        and feed it each tracked pose (``predictor.update``); the motion model stays the fallback."""
        self.imu_predictor = predictor

    def imu_state(self, timestamp: float) -> tuple[np.ndarray, np.ndarray] | None:
        """Inertial sensors: ``(velocity (3,), bias (6,) gyro then accelerometer)`` of the IMU
        prediction at ``timestamp`` (a keyframe's initial state), or None without one."""
        p = self.imu_predictor
        v = p.velocity_at(timestamp) if p is not None and p.active else None
        if v is None:
            return None
        return v, np.concatenate([p.bias.gyro, p.bias.accel])

    def move_world(self, S: np.ndarray) -> None:
        """The whole map moved by the similarity ``S`` (the IMU initialization's gravity alignment and
        scale): move the last poses, and scale the velocity and speed, with it."""
        st = self.state
        s = similarity_scale(S)
        mm = st.motion_model
        if mm.T_world_last is not None:
            mm.T_world_last = move_pose(S, mm.T_world_last)
            mm.T_last_cur = mm.T_last_cur.copy()
            mm.T_last_cur[:3, 3] *= s
        if st.T_world_last_good is not None:
            st.T_world_last_good = move_pose(S, st.T_world_last_good)
        st.speed_per_frame *= s

    def start_in_map(self, max_frames_to_place: int) -> None:
        """The map holds keyframes of an earlier session: place the next frames in it by global
        relocalization (any segment) instead of bootstrapping a new segment; after
        ``max_frames_to_place`` frames that cannot be placed (0: at once), bootstrap a new segment
        past the map's highest segment id."""
        st = self.state
        st.segment = max((k.segment for k in self.map.keyframes.values()), default=-1)
        if max_frames_to_place <= 0:  # no placing: the first bootstrap starts a new segment past the loaded ones
            return
        st.status = "placing"
        self._place_left = int(max_frames_to_place)

    def segment_merged(self, old: int, new: int, S_new_old: np.ndarray) -> None:
        """Segment ``old`` was joined into ``new``, its world mapped by the similarity ``S_new_old``
        (:mod:`vslam.loop.segment_merging`): when tracking in ``old``, go on in ``new`` from the
        moved last poses (the velocity scaled with a monocular merge's scale)."""
        st = self.state
        if st.segment != old:
            return
        st.segment = new
        st.local_ids = None
        self.move_world(S_new_old)
        p = self.imu_predictor
        if p is not None and p.active:  # the IMU state moves with the segment (a 4-DoF join is rigid)
            if abs(similarity_scale(S_new_old) - 1.0) < 1e-9:
                p.apply_correction(S_new_old)
            else:
                p.stop("its map segment was joined under a scale change")

    @property
    def motion_model(self) -> MotionModel:
        return self.state.motion_model

    @property
    def segment(self) -> int:
        """Index of the current map segment (-1 before the first)."""
        return self.state.segment

    @property
    def dense_links(self) -> dict:
        """RGB-D: ``{kf_id: DenseLink}`` of keyframes posed by dense alignment (local BA keeps them)."""
        return self.dense.dense_links

    @property
    def n_depth_bridged(self) -> int:
        return self.dense.n_bridged

    @property
    def n_depth_refined(self) -> int:
        return self.dense.n_refined

    def detect(self, frame: Frame, gray: np.ndarray | None = None) -> Observation:
        """The keypoints (with depth) the tracker would detect in ``frame``; no state changes."""
        return self.observer.detect(frame, frame.gray if gray is None else gray)

    _detect = detect  # the name tests of other stages use

    def prepare(self, frame: Frame) -> None:
        """Work on ``frame`` that needs no tracking state (grayscale conversion and, with
        ``association=match``, feature detection and the stereo depth of the features), safe to run
        in another thread ahead of :meth:`track` (the runner's decoding thread calls it, see
        :func:`vslam.runner.run_sequence`). Uses its own detector instance; :meth:`track` picks the
        result up by frame identity."""
        t0 = time.perf_counter()
        gray, feats = self._preparer(frame)
        self.adopt_prepared(frame, gray, feats, time.perf_counter() - t0)

    def preparer(self) -> FramePreparer:
        """A picklable copy of what :meth:`prepare` runs, to run it in another process; hand its
        result to :meth:`adopt_prepared`."""
        return FramePreparer(self.fcfg, self.cfg.association, self.camera, self.sensor, self.cfg.depth)

    def adopt_prepared(self, frame: Frame, gray: np.ndarray, feats: Any, seconds: float = 0.0) -> None:
        """Take a :class:`FramePreparer` result for ``frame`` (computed elsewhere, e.g. by the
        runner's prefetch process); :meth:`track` uses it when it gets this very ``frame``."""
        if len(self._prepared) > 64:  # never consumed (frames dropped by the caller): keep memory flat
            self._prepared.clear()
        self._prepared[frame.index] = (frame, gray, feats)
        self.timers["prepare"] += seconds

    def track(self, frame: Frame) -> TrackOutput:
        """Track one frame: its pose (None when lost or initializing) and whether it became a keyframe."""
        st = self.state
        self.n_frames += 1
        prep = self._prepared.pop(frame.index, None)
        if prep is not None and prep[0] is frame:
            gray, self.observer.prepared_feats = prep[1], prep[2]
        else:
            gray, self.observer.prepared_feats = frame.gray, None
        t0 = time.perf_counter()
        T_world_pred = self._predict(frame) if st.status not in ("initializing", "placing") else None
        obs, _ = self.observer.observe(frame, gray, T_world_pred, st.prev, st.prev_gray, st.motion_model.valid)
        self.timers["features"] += time.perf_counter() - t0
        if st.status == "initializing":
            out = self.bootstrap.initialize(frame, gray, obs)
        elif st.status == "placing":
            out = self._place(frame, gray, obs)
        else:
            out = self._track_initialized(frame, gray, obs, T_world_pred)
        if self.sensor == "rgbd":
            self.dense.end_frame(frame, gray, out.T_world_cam, out.is_keyframe, out.ref_keyframe)
        if self.imu_predictor is not None and out.state == "ok" and out.T_world_cam is not None:
            self.imu_predictor.update(frame.timestamp, out.T_world_cam)
        return out

    def _predict(self, frame: Frame) -> np.ndarray | None:
        """The pose prediction: the IMU's once initialized (when it covers the frame), else the
        constant-velocity model's."""
        self._imu_pred = None
        if self.imu_predictor is not None:
            T_world_pred = self._imu_pred = self.imu_predictor.predict(frame.timestamp)
            if T_world_pred is not None:
                return T_world_pred
        return self.state.motion_model.predict()

    # ================================================================== tracking
    def _local_point_ids(self) -> np.ndarray:
        st = self.state
        if st.local_ids is None:
            kfs = self.map.local_keyframes(st.ref_kf, self.n_local_keyframes) if st.ref_kf is not None else []
            st.local_ids = self.map.local_point_ids(kfs)
        ids = st.local_ids
        return ids[self.map.points.alive[ids]]

    def _track_initialized(self, frame: Frame, gray: np.ndarray, obs: Observation, T_world_pred) -> TrackOutput:
        cfg, st = self.cfg, self.state
        if cfg.motion == "2d2d":
            T_world_cam, n_inl = self.two_view.pose(obs, st.motion_model)
        else:
            T_world_cam, n_inl = self.local_map.track(obs, T_world_pred, self._local_point_ids(), st.prev,
                                                      relocalize=st.status == "lost")
            if T_world_cam is None and self._relocalizer is not None:
                T_world_cam, n_inl = self._relocalize(obs)
        if T_world_cam is None:
            return self._lost(frame, gray, obs)
        if self.imu_predictor is not None:
            T_world_cam = self._inertial_pose(frame, obs, T_world_cam)
        return self._tracked(frame, gray, obs, T_world_cam, n_inl)

    def _inertial_pose(self, frame: Frame, obs: Observation, T_world_cam: np.ndarray) -> np.ndarray:
        """Inertial sensors, IMU initialized: the frame's pose, velocity and biases optimized against the
        IMU motion since the newest keyframe and the inlier reprojections
        (:meth:`ImuPredictor.optimize`); the visual pose when that cannot run."""
        t0 = time.perf_counter()
        kf = self._inertial_anchor()
        T = None
        if kf is not None:
            sel = np.flatnonzero(obs.point_ids >= 0)
            X_world = self.map.points.position[obs.point_ids[sel]]
            T = self.imu_predictor.optimize(frame.timestamp, T_world_cam, kf, X_world, obs.uv_undist[sel],
                                            obs.sigma[sel], None if obs.u_right is None else obs.u_right[sel],
                                            self.camera, self.local_map.bf)
        self.timers["imu_pose"] = self.timers.get("imu_pose", 0.0) + time.perf_counter() - t0
        return T_world_cam if T is None else T

    def _inertial_anchor(self) -> KeyFrame | None:
        """The keyframe the inertial pose optimization holds fixed: the newest of the segment, or
        with the predictor's ``anchors`` the newest whose state a visual-inertial BA estimated."""
        st, anchors = self.state, self.imu_predictor.anchors
        kf = self.map.keyframes.get(st.last_kf) if st.last_kf is not None else None
        if anchors is None or kf is None or kf.id in anchors:
            return kf if kf is not None and kf.segment == st.segment else None
        ids = [k for k in anchors if k in self.map.keyframes and self.map.keyframes[k].segment == st.segment
               and not self.map.keyframes[k].bad]
        return self.map.keyframes[max(ids, key=lambda k: self.map.keyframes[k].timestamp)] if ids else None

    def _tracked(self, frame: Frame, gray: np.ndarray, obs: Observation, T_world_cam: np.ndarray,
                 n_inl: int) -> TrackOutput:
        """The frame has a pose: dense refinement, keyframe decision, state update."""
        cfg, st = self.cfg, self.state
        if cfg.dense.refine and self.sensor == "rgbd" and cfg.motion != "2d2d" and n_inl < cfg.dense.refine_max_inliers:
            T_world_cam = self.dense.refine(frame, gray, T_world_cam, st.motion_model, st.T_world_last_good)
        t0 = time.perf_counter()
        st.status = "ok"
        st.n_lost_run = 0
        st.frames_since_kf += 1
        st.count_reference(int((obs.point_ids >= 0).sum()))
        is_kf = decide_keyframe(cfg, self.sensor, obs, T_world_cam, self.map.keyframes.get(st.ref_kf),
                                st.frames_since_kf, st.kf_ref_tracked, n_inl, self.dense.wants_keyframe(), st.revisiting,
                                inertial=self.imu_predictor is not None and self.imu_predictor.active)
        if is_kf:
            self._insert_keyframe(frame, gray, obs, T_world_cam)
        else:
            self._follow_revisit(obs)
        self.timers["mapping"] += time.perf_counter() - t0
        st.tracked(T_world_cam, obs, gray)
        return TrackOutput(T_world_cam, "ok", is_kf, n_inl, st.ref_kf)

    def _follow_revisit(self, obs: Observation) -> None:
        """On a revisit the reference keyframe (and the local map around it) moves to the old
        keyframe sharing most points with this frame (:func:`revisit_reference`); the tracked-points
        ratio of the keyframe decision restarts (:meth:`TrackingState.revisit`)."""
        st = self.state
        if st.ref_kf is None or self.cfg.keyframes.revisit_min_age <= 0 or self.cfg.motion == "2d2d":
            return
        best = revisit_reference(self.map, self.map.local_keyframes(st.ref_kf, self.n_local_keyframes),
                                 obs.point_ids, st.last_kf, self.cfg.keyframes.revisit_min_age)
        if best is not None and best != st.ref_kf:
            log.debug("revisit: reference keyframe %s -> %d", st.ref_kf, best)
            st.revisit(best, keep_floor=self.sensor == "mono" and self.cfg.keyframes.revisit_floor_mono)

    def _insert_keyframe(self, frame: Frame, gray: np.ndarray, obs: Observation, T_world_cam: np.ndarray) -> None:
        kf = self.keyframes.insert(frame, gray, obs, T_world_cam, self.state.segment)
        self.state.keyframe_inserted(kf.id)

    def _place(self, frame: Frame, gray: np.ndarray, obs: Observation) -> TrackOutput:
        """Status ``placing`` (:meth:`start_in_map`): global relocalization in any segment of the
        loaded map; the frame is reported lost until one is placed."""
        st = self.state
        T, n = (None, 0) if self._relocalizer is None else self._relocalize(obs, segment=None, recover=False)
        if T is not None:
            st.segment = self.map.keyframes[st.ref_kf].segment
            log.info("frame %d placed in the loaded map (segment %d) with %d inliers", frame.index, st.segment, n)
            if self.placed is None:
                self.placed = (int(frame.index), int(st.ref_kf), int(n))
            return self._tracked(frame, gray, obs, T, n)
        self._place_left -= 1
        st.set_prev(obs, gray)
        if self._place_left > 0:
            return TrackOutput(None, "lost", False, 0)
        log.warning("no frame placed in the loaded map: starting a new map segment")
        self._reinitialize()
        if self.sensor != "mono":
            obs.point_ids[:] = -1
            return self.bootstrap.initialize(frame, gray, obs)
        return TrackOutput(None, "initializing", False, 0)

    def _relocalize(self, obs: Observation, segment: int | None | str = "current",
                    recover: bool = True) -> tuple[np.ndarray | None, int]:
        """Tracking against the local map failed: find the pose among all keyframes of this map
        segment (bag-of-words candidates + PnP, :class:`vslam.loop.relocalization.Relocalizer`),
        then refine it against that keyframe's local map. First (no place recognition) against the
        reference and last keyframes, with the lower thresholds of ``Relocalizer.recover``: after a
        wide-baseline motion the constant-velocity prediction is useless but the map is not."""
        st = self.state
        r = None
        if recover and hasattr(self._relocalizer, "recover") and st.ref_kf is not None:
            r = self._relocalizer.recover(obs, [st.ref_kf, st.last_kf])
        if r is None:
            r = self._relocalizer(obs, segment=st.segment if segment == "current" else segment)
        if r is None:
            return None, 0
        st.ref_kf = r.keyframe_id
        st.local_ids = None
        T, n = self.local_map.track(obs, r.T_world_cam, self._local_point_ids(), st.prev, relocalize=True)
        if T is None:
            obs.point_ids[:] = -1
            obs.point_ids[r.kp_idx] = r.point_ids
            T, n = r.T_world_cam, r.n_inliers
        st.motion_model.reset(T)
        self.n_relocalized += 1
        log.info("relocalized against keyframe %d with %d inliers", r.keyframe_id, n)
        return T, n

    def _lost(self, frame: Frame, gray: np.ndarray, obs: Observation) -> TrackOutput:
        st = self.state
        if self.sensor == "rgbd":
            bridged = self._bridge_with_depth(frame, gray, obs)
            if bridged is not None:
                return bridged
        imu_only = self._imu_only(frame, gray, obs)
        if imu_only is not None:
            return imu_only
        st.n_lost_run += 1
        st.status = "lost"
        log.info("frame %d lost (%d in a row)", frame.index, st.n_lost_run)
        if st.n_lost_run >= self.max_lost_frames:
            self._reinitialize()
            if self.sensor != "mono":  # depth sensors restart a map segment on this very frame
                obs.point_ids[:] = -1
                out = self.bootstrap.initialize(frame, gray, obs)
                if out.T_world_cam is not None:
                    return out
                st.status = "lost"
                return TrackOutput(None, "lost", False, 0)
        st.set_prev(obs, gray)
        # keep predicting from the last good pose: advance the motion model by one frame
        mm = st.motion_model
        if mm.T_world_last is not None:
            mm.T_world_last = mm.T_world_last @ mm.T_last_cur
        return TrackOutput(None, "lost", False, 0)

    def _imu_only(self, frame: Frame, gray: np.ndarray, obs: Observation) -> TrackOutput | None:
        """Inertial sensors, IMU initialized, vision failed: the IMU prediction is the frame's pose
        (state ``imu``) while the last visually tracked frame is at most ``tracking.imu_only_max_s``
        seconds back (ORB-SLAM3's RECENTLY_LOST). The IMU state stays at that frame, so each
        prediction integrates from it; the tracker stays *lost* in the same map segment (no lost-run
        count, no new segment), and the next frames are tracked against the local map from the
        prediction (wider search radius), or relocalized."""
        p, T_pred, st = self.imu_predictor, self._imu_pred, self.state
        if p is None or T_pred is None or not p.active or frame.timestamp - p.t > self.cfg.tracking.imu_only_max_s:
            return None
        st.status = "lost"
        st.set_prev(obs, gray)
        st.motion_model.T_world_last = T_pred.copy()
        self.n_imu_only += 1
        log.info("frame %d: no visual pose, IMU-only (%.2f s since the last tracked frame)", frame.index,
                 frame.timestamp - p.t)
        return TrackOutput(T_pred, "imu", False, 0, st.ref_kf)

    def _bridge_with_depth(self, frame: Frame, gray: np.ndarray, obs: Observation) -> TrackOutput | None:
        """RGB-D, no pose from features: dense alignment to the last tracked frame
        (:meth:`DenseTracker.bridge`). If the depths agree, the frame becomes a keyframe of fresh
        depth points in the *same* map segment (a later loop closure can still correct the whole
        map) instead of a lost frame and, after ``tracking.max_lost_frames``, a new segment with an
        extrapolated origin."""
        st = self.state
        T_world_cam = self.dense.bridge(frame, gray, st.motion_model, st.T_world_last_good)
        if T_world_cam is None:
            return None
        n = int(np.isfinite(obs.depth).sum())
        obs.point_ids[:] = -1
        t0 = time.perf_counter()
        self._insert_keyframe(frame, gray, obs, T_world_cam)
        self.timers["mapping"] += time.perf_counter() - t0
        st.tracked(T_world_cam, obs, gray, speed=False)
        return TrackOutput(T_world_cam, "ok", True, n, st.ref_kf)

    def _reinitialize(self) -> None:
        st = self.state
        log.warning("tracking lost for %d frames: re-initializing a new map segment", st.n_lost_run)
        if self.imu_predictor is not None:  # the new segment has its own world (and scale)
            self.imu_predictor.stop("a new map segment starts")
        st.status = "initializing"
        self.bootstrap.reset()
        st.ref_kf = None
        st.last_kf = None
        st.local_ids = None
        st.revisiting = False
        self.two_view.reset()
        if st.motion_model.T_world_last is not None:
            st.T_world_last_good = st.motion_model.T_world_last.copy()
        st.prev = None
