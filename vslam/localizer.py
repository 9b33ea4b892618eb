"""Localization in a fixed, previously built map (``vslam localize``).

Each frame is either

* **relocalized** globally when there is no pose (cold start, or after losing track): BoW
  candidates from the keyframe database, descriptor matching to the candidate's covisible map
  points, PnP RANSAC and guided-matching refinement (:class:`vslam.loop.relocalization.Relocalizer`,
  ORB-SLAM sec. V-C), then one tracking pass against the local map at that pose; or
* **tracked** against the map: a constant-velocity prediction, projection of the map points of
  the keyframes near the predicted pose, guided matching and robust pose refinement
  (ORB-SLAM's ``TrackWithMotionModel`` + ``TrackLocalMap``, Mur-Artal et al. 2015, sec. V-B/D).
  With too few inliers the frame falls back to global relocalization.

With an IMU (an inertial sensor in a gravity-aligned map, :mod:`vslam.localizer_imu`) the IMU
predicts each frame in place of the constant-velocity model, and a frame that vision cannot
localize takes the IMU prediction as its pose (state ``imu``) for up to about a second.

Frames that cannot be localized get ``T_world_cam = None`` (never a guess). The map is never
modified: no points, keyframes or statistics (``found``/``visible``) are written.
"""
from __future__ import annotations

import dataclasses
import logging
import time
from collections import defaultdict
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from vslam.config import LocalizerConfig
from vslam.features import create_detector
from vslam.map.matching import brute_force_match, guided_match, project_local_points
from vslam.frontend.observation import sample_depth
from vslam.frontend.prepare import FramePreparer
from vslam.geometry.lie import inv_se3
from vslam.geometry.pnp import pnp_ransac, refine_pose
from vslam.geometry.camera import PinholeCamera, stereo_bf
from vslam.map.map import Map
from vslam.stream import warm_kernels
from vslam.trajectory import Trajectory

log = logging.getLogger(__name__)


@dataclass
class LocalizeResult:
    """The outcome for one frame: ``state`` is ``localized`` (global relocalization), ``tracking``
    (tracked from the previous pose), ``imu`` (the IMU's prediction alone) or ``lost`` (``T_world_cam`` None). The shape of a
    :class:`vslam.stream.FrameResult` (a localized frame is never a keyframe: the map is fixed)."""

    T_world_cam: np.ndarray | None
    state: str
    n_inliers: int
    is_keyframe: bool = False


@dataclass
class _Obs:
    """The frame's keypoints, in the attribute layout the Relocalizer expects."""

    uv: np.ndarray
    uv_undist: np.ndarray
    descriptors: np.ndarray
    octave: np.ndarray
    depth: np.ndarray
    u_right: np.ndarray | None


class Localizer:
    """Streaming localizer: ``localizer.track(frame) -> LocalizeResult`` (see the module docstring);
    a :class:`vslam.stream.FrameTracker`, so :func:`vslam.runner.run_sequence` drives it as it
    drives the SLAM system.

    Args:
        slam_map: the loaded map (read only).
        database: its keyframe database, or None (then one is built from the keyframes' descriptors).
        camera: intrinsics of the frames to localize.
        config: the root :class:`vslam.config.Config` (its ``features`` and ``loop.relocalization``
            sections are used), or None for defaults.
        sensor: ``mono``, ``stereo`` or ``rgbd`` (depth is used only as extra constraints).
        localize_config: :class:`LocalizerConfig`.
        vocabulary: BoW vocabulary (default: the packaged one).
        imu: the IMU state of an inertial sensor in a gravity-aligned map
            (:class:`vslam.localizer_imu.LocalizerImu`), or None (visual only).
    """

    def __init__(self, slam_map: Map, database: Any, camera: PinholeCamera, config: Any = None,
                 sensor: str = "mono", localize_config: LocalizerConfig | None = None,
                 vocabulary: Any = None, imu: Any = None) -> None:
        from vslam.config import Config
        from vslam.loop import load_default_vocabulary
        from vslam.loop.relocalization import Relocalizer

        self._kernels_ms = warm_kernels()  # the compiled kernels loaded now, not in the first frames
        cfg = config if config is not None else Config()
        self.config = cfg
        self.cfg = localize_config or LocalizerConfig()
        self.map = slam_map
        self.camera = camera
        self.sensor = sensor
        self.features = cfg.features.for_sensor(sensor)  # features.subpixel=auto resolved as the map's run did
        self.detector = create_detector(self.features)
        self.scale_factor = float(getattr(cfg.features, "scale_factor", 1.2))
        self.bf = stereo_bf(camera, sensor)
        vocab = vocabulary if vocabulary is not None else load_default_vocabulary()
        reloc_cfg = cfg.loop.relocalization
        if self.cfg.reloc_min_inliers is not None:
            reloc_cfg = dataclasses.replace(reloc_cfg, min_inliers=self.cfg.reloc_min_inliers)
        self.relocalizer = Relocalizer(slam_map, camera, sensor, vocab, database, reloc_cfg,
                                       self.scale_factor, self.bf, refine_ransac=self.cfg.reloc_refine_ransac)
        if database is None:  # a private database, filled once from the map's keyframes
            for kf_id in sorted(slam_map.keyframes):
                self.relocalizer.add_keyframe(slam_map.keyframes[kf_id])
        # keyframe geometry for choosing the local map near a pose
        kfs = [kf for kf in (slam_map.keyframes[i] for i in sorted(slam_map.keyframes)) if not getattr(kf, "bad", False)]
        self._kf_ids = np.array([kf.id for kf in kfs], dtype=np.int64)
        T = np.stack([kf.T_world_cam for kf in kfs]) if kfs else np.zeros((0, 4, 4))
        self._kf_centres = T[:, :3, 3]
        self._kf_axes = T[:, :3, 2]
        self._alive = slam_map.points.alive[: len(slam_map.points)].copy()
        # state
        self.T_world_last: np.ndarray | None = None
        self.T_world_prev: np.ndarray | None = None
        self.imu = imu
        self.ref_kf: int | None = None
        self.counts: dict[str, int] = defaultdict(int)
        self.timers: dict[str, float] = defaultdict(float)
        self._timestamps: list[float] = []  # the localized frames, for trajectory()
        self._poses: list[np.ndarray] = []
        self._preparer = FramePreparer(self.features, "match")  # its own detector, for the decoding thread
        self._prepared: dict[int, tuple[Any, Any]] = {}  # frame index -> (frame, features found ahead)

    # ------------------------------------------------------------------ public
    def reset(self) -> None:
        """Forget the pose (the next frame is relocalized globally)."""
        self.T_world_last = self.T_world_prev = None
        self.ref_kf = None

    def track(self, frame: Any) -> LocalizeResult:
        """Localize one :class:`~vslam.datasets.frame.Frame` in the map."""
        self.counts["frames"] += 1
        t = float(frame.timestamp)
        t0 = time.perf_counter()
        obs = self._observe(frame)
        self.timers["features"] += time.perf_counter() - t0
        result: LocalizeResult | None = None
        if self.T_world_last is not None:
            t0 = time.perf_counter()
            result = self._track(obs, self.imu.predict(t) if self.imu is not None else None)
            self.timers["track"] += time.perf_counter() - t0
            if result is None:
                self.counts["track_failures"] += 1
        if result is None:
            t0 = time.perf_counter()
            result = self._relocalize(obs)
            self.timers["relocalize"] += time.perf_counter() - t0
        if result.T_world_cam is None and self.imu is not None and self.T_world_last is not None:
            T_imu = self.imu.bridge(t)  # vision failed: the IMU carries the pose (localizer_imu)
            if T_imu is not None:
                result = LocalizeResult(T_imu, "imu", 0)
        if result.T_world_cam is None:
            self.counts["lost"] += 1
            self.reset()
            if self.imu is not None:
                self.imu.forget()
        else:
            self.counts[result.state] += 1
            # velocity only between consecutive tracked frames: a relocalized pose may jump by the
            # map's local inconsistency, so the next frame starts without a velocity
            self.T_world_prev = self.T_world_last if result.state == "tracking" else None
            self.T_world_last = result.T_world_cam
            if self.imu is not None and result.state != "imu":
                self.imu.localized(t, result.T_world_cam)
            self._timestamps.append(t)
            self._poses.append(result.T_world_cam)
        return result

    def finish(self) -> None:
        """End of input (nothing pending: the map is fixed)."""

    def trajectory(self) -> Trajectory:
        """The localized frames' poses (in the map's world frame), as tracked."""
        poses = np.stack(self._poses) if self._poses else np.zeros((0, 4, 4))
        return Trajectory(np.asarray(self._timestamps, float), poses)

    def stats(self) -> dict:
        """Counts (frames, localized = tracked + relocalized and its ratio, tracked, relocalizations,
        relocalization attempts, track failures, implausible steps, lost) and per-stage mean
        milliseconds."""
        n = max(self.counts["frames"], 1)
        n_loc = self.counts["tracking"] + self.counts["localized"]
        imu = {} if self.imu is None else {"imu_used": True, "imu_only_frames": self.counts["imu"],
                                           "imu_predicted_frames": self.imu.n_predicted}
        return {
            "frames": self.counts["frames"],
            "localized": n_loc,
            "localized_ratio": round(n_loc / self.counts["frames"], 4) if self.counts["frames"] else 0.0,
            "tracked": self.counts["tracking"],
            "relocalizations": self.counts["localized"],
            "relocalization_attempts": self.relocalizer.attempts,
            "track_failures": self.counts["track_failures"],
            "implausible_steps": self.counts["implausible_steps"],
            "lost": self.counts["frames"] - n_loc - self.counts["imu"],  # every frame without a pose (= counts["lost"])
            **imu,
            "stage_ms": {k: round(1000.0 * v / n, 2) for k, v in self.timers.items()},
            "startup_ms": {"kernels": self._kernels_ms},  # loading the compiled kernels (vslam.stream)
        }

    # ------------------------------------------------------------------ prefetch hooks (vslam.stream)
    def prepare(self, frame: Any) -> None:
        """Detect ``frame``'s features ahead of :meth:`track`, in the run loop's decoding thread
        (its own detector; the same features :meth:`track` would find)."""
        t0 = time.perf_counter()
        result = self._preparer(frame)
        self.adopt_prepared(frame, result, time.perf_counter() - t0)

    def frame_preparer(self) -> FramePreparer:
        """What :meth:`prepare` runs, picklable, for a decoding process; its results go to
        :meth:`adopt_prepared`."""
        return FramePreparer(self.features, "match")

    def adopt_prepared(self, frame: Any, result: tuple[Any, Any], seconds: float = 0.0) -> None:
        """Take a :meth:`frame_preparer` result ``(gray, features)`` for ``frame``; :meth:`track`
        uses it when it gets this very frame."""
        if len(self._prepared) > 64:  # never consumed (frames dropped by the caller): keep memory flat
            self._prepared.clear()
        self._prepared[frame.index] = (frame, result[1])
        self.timers["prepare"] += seconds

    # ------------------------------------------------------------------ features
    def _observe(self, frame: Any) -> _Obs:
        prep = self._prepared.pop(getattr(frame, "index", None), None)
        feats = prep[1] if prep is not None and prep[0] is frame else self.detector.detect(frame.gray)
        uv = np.asarray(feats.uv, dtype=float).reshape(-1, 2)
        uv_undist = self.camera.undistort_points(uv) if len(uv) else uv
        n = len(uv)
        depth = np.full(n, np.nan)
        if self.sensor == "rgbd" and getattr(frame, "depth", None) is not None and n:
            fc = self.config.frontend
            depth = sample_depth(frame.depth, uv, fc.depth.min_depth, fc.depth.max_depth)
        u_right = uv_undist[:, 0] - self.bf / depth if (self.bf > 0 and self.cfg.use_depth) else None
        desc = feats.descriptors if feats.descriptors is not None else np.zeros((0, 32), np.uint8)
        return _Obs(uv, uv_undist, desc, np.asarray(feats.octave, dtype=np.int32).reshape(-1), depth, u_right)

    # ------------------------------------------------------------------ local map
    def _local_keyframes(self, T_world_cam: np.ndarray) -> list[int]:
        """Keyframes nearest to the camera centre that look roughly the same way, plus the
        covisible keyframes of the reference keyframe."""
        cfg = self.cfg
        if len(self._kf_ids) == 0:
            return []
        c, axis = T_world_cam[:3, 3], T_world_cam[:3, 2]
        dist = np.linalg.norm(self._kf_centres - c, axis=1)
        cos = self._kf_axes @ axis
        ok = cos >= np.cos(np.radians(cfg.max_view_angle_deg))
        cand = np.flatnonzero(ok) if ok.any() else np.arange(len(dist))
        near = cand[np.argsort(dist[cand], kind="stable")[: cfg.n_near_keyframes]]
        ids = self._kf_ids[near].tolist()
        ref = self.ref_kf if self.ref_kf is not None else ids[0]
        group = list(dict.fromkeys(ids + [ref] + self.map.covisible(ref, cfg.n_covisible)))
        return group

    def _local_points(self, group: list[int]) -> np.ndarray:
        ids = self.map.local_point_ids(group)
        ids = ids[ids < len(self._alive)]
        return ids[self._alive[ids]]

    # ------------------------------------------------------------------ tracking
    def _predict(self) -> np.ndarray:
        """Constant velocity: ``T_pred = T_last (T_prev^-1 T_last)``; large steps are dropped."""
        T_last = self.T_world_last
        if self.T_world_prev is None:
            return T_last.copy()
        V = inv_se3(self.T_world_prev) @ T_last
        ang = np.degrees(np.arccos(np.clip((np.trace(V[:3, :3]) - 1.0) / 2.0, -1.0, 1.0)))
        if np.linalg.norm(V[:3, 3]) > self.cfg.max_velocity_m or ang > self.cfg.max_velocity_deg:
            return T_last.copy()
        return T_last @ V

    def _track(self, obs: _Obs, T_world_imu_pred: np.ndarray | None = None) -> LocalizeResult | None:
        """Track against the fixed map from the IMU's prediction ``T_world_imu_pred`` when there is one,
        else the constant-velocity prediction; None if too few inliers."""
        if len(obs.uv_undist) < self.cfg.min_inliers:
            return None
        guided = self.T_world_prev is not None or T_world_imu_pred is not None  # a prediction with motion
        T_world_pred = self._predict() if T_world_imu_pred is None else T_world_imu_pred
        if T_world_imu_pred is not None:
            self.imu.n_predicted += 1
        pts = self._local_points(self._local_keyframes(T_world_pred))
        tree = cKDTree(obs.uv_undist)
        if not guided:
            # no velocity yet (just relocalized): a window around the last pose may hold only wrong
            # matches that agree on a wrong pose (repetitive texture); match the local map by
            # descriptors alone and let PnP RANSAC find the pose
            T_cw, kp, pid = self._match_unguided(obs, pts)
        else:
            T_cw, kp, pid = self._match_and_refine(obs, pts, inv_se3(T_world_pred), self.cfg.search_radius_px, tree,
                                                   ransac=self.cfg.always_ransac)
        if len(kp) < self.cfg.min_first_pass_inliers:
            # a poor prediction: wide window, and PnP RANSAC before refinement (the Huber refinement
            # from a far-off guess can settle in a wrong minimum among the many wrong matches)
            T_cw, kp, pid = self._match_and_refine(obs, pts, inv_se3(T_world_pred), self.cfg.search_radius_wide_px,
                                                   tree, ransac=True)
        if len(kp) < self.cfg.min_first_pass_inliers and guided:
            # still too few: the local map by descriptors alone (ORB-SLAM's TrackReferenceKeyFrame)
            T_cw, kp, pid = self._match_unguided(obs, pts)
        if len(kp) < self.cfg.min_first_pass_inliers:
            return None
        res = self._finish(obs, T_cw, tree, "tracking", pts)
        # (no velocity: the pose came from unguided matching + RANSAC, as robust as a relocalization)
        if res is not None and guided and not self._plausible(T_world_pred, res.T_world_cam):
            self.counts["implausible_steps"] += 1
            return None
        return res

    def _plausible(self, T_world_pred: np.ndarray, T_world_cam: np.ndarray) -> bool:
        """Whether ``T_world_cam`` lies within ``max_step_m`` / ``max_step_deg`` of the prediction."""
        D = inv_se3(T_world_pred) @ T_world_cam
        ang = np.degrees(np.arccos(np.clip((np.trace(D[:3, :3]) - 1.0) / 2.0, -1.0, 1.0)))
        return bool(np.linalg.norm(D[:3, 3]) <= self.cfg.max_step_m and ang <= self.cfg.max_step_deg)

    def _finish(self, obs: _Obs, T_cw: np.ndarray, tree: cKDTree, state: str,
                pts: np.ndarray | None = None) -> LocalizeResult | None:
        """Second pass (TrackLocalMap): the local map around the refined pose, tight radius."""
        T_world = inv_se3(T_cw)
        self.ref_kf = self._nearest_keyframe(T_world)
        pts2 = self._local_points(self._local_keyframes(T_world))
        if pts is not None:
            pts2 = np.union1d(pts, pts2)
        T_cw2, kp, pid = self._match_and_refine(obs, pts2, T_cw, self.cfg.refine_radius_px, tree)
        if len(kp) < self.cfg.min_inliers:
            return None
        return LocalizeResult(inv_se3(T_cw2), state, int(len(kp)))

    def _nearest_keyframe(self, T_world_cam: np.ndarray) -> int | None:
        if len(self._kf_ids) == 0:
            return None
        dist = np.linalg.norm(self._kf_centres - T_world_cam[:3, 3], axis=1)
        cos = self._kf_axes @ T_world_cam[:3, 2]
        dist = np.where(cos >= np.cos(np.radians(self.cfg.max_view_angle_deg)), dist, dist + 1e3)
        return int(self._kf_ids[int(np.argmin(dist))])

    def _match_unguided(self, obs: _Obs, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Ratio + mutual descriptor matching of the keypoints to ``pts``, PnP RANSAC, refinement."""
        store = self.map.points
        empty = np.zeros(0, np.int64)
        if len(pts) < 6 or store.descriptor is None or len(obs.descriptors) < 6:
            return np.eye(4), empty, empty
        m, k = brute_force_match(store.descriptor[pts], obs.descriptors, True, ratio=0.8,
                                 max_distance=self.cfg.max_descriptor_distance)
        if len(m) < self.cfg.min_first_pass_inliers:
            return np.eye(4), empty, empty
        pid = pts[m]
        T_cw, inl = pnp_ransac(store.position[pid], obs.uv_undist[k], self.camera.K, None,
                               self.relocalizer.config.reproj_px, 200)
        if T_cw is None or inl.sum() < self.cfg.min_first_pass_inliers:
            return np.eye(4), empty, empty
        k, pid = k[inl], pid[inl]
        sigma = np.power(self.scale_factor, obs.octave[k].astype(float))
        ur = None if obs.u_right is None else obs.u_right[k]
        T_cw, inl = refine_pose(T_cw, store.position[pid], obs.uv_undist[k], self.camera.K, sigma, ur, self.bf)
        return T_cw, k[inl], pid[inl]

    def _match_and_refine(self, obs: _Obs, pts: np.ndarray, T_cw: np.ndarray, radius: float, tree: cKDTree,
                          ransac: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Project ``pts`` at ``T_cw``, guided-match within ``radius`` px, refine the pose (Huber
        Gauss-Newton with the chi-square inlier test). Returns ``(T_cam_world, kp_idx, point_ids)`` of
        the inliers. ``ransac``: PnP RANSAC on the matches first (the refinement starts from its pose)."""
        store = self.map.points
        empty = np.zeros(0, np.int64)
        if len(pts) == 0 or store.descriptor is None:
            return T_cw, empty, empty
        vis, proj, _ = project_local_points(store, pts, T_cw, self.camera,
                                            max_view_angle_cos=float(np.cos(np.radians(self.cfg.max_point_view_angle_deg))),
                                            check_distance=self.cfg.check_point_distance)
        if len(vis) < 6:
            return T_cw, empty, empty
        m, k, _ = guided_match(proj, store.descriptor[vis], obs.uv_undist, obs.descriptors, radius, True,
                               self.cfg.max_descriptor_distance, self.cfg.match_ratio, kp_tree=tree)
        if len(m) < 6:
            return T_cw, empty, empty
        pid = vis[m]
        if ransac:
            T_r, inl = pnp_ransac(store.position[pid], obs.uv_undist[k], self.camera.K, T_cw,
                                  self.relocalizer.config.reproj_px, 200)
            if T_r is None or inl.sum() < self.cfg.min_first_pass_inliers:
                return T_cw, empty, empty
            T_cw = T_r
        sigma = np.power(self.scale_factor, obs.octave[k].astype(float))
        ur = None if obs.u_right is None else obs.u_right[k]
        T_cw2, inl = refine_pose(T_cw, store.position[pid], obs.uv_undist[k], self.camera.K, sigma, ur, self.bf)
        if not np.all(np.isfinite(T_cw2)):
            return T_cw, empty, empty
        return T_cw2, k[inl], pid[inl]

    # ------------------------------------------------------------------ relocalization
    def _relocalize(self, obs: _Obs) -> LocalizeResult:
        """Global relocalization, then one local-map tracking pass at the relocalized pose."""
        reloc = self.relocalizer(obs) if len(obs.descriptors) else None
        if reloc is None:
            return LocalizeResult(None, "lost", 0)
        self.ref_kf = int(reloc.keyframe_id)
        tree = cKDTree(obs.uv_undist)
        res = self._finish(obs, inv_se3(reloc.T_world_cam), tree, "localized")
        if res is None:
            # the local map does not confirm the relocalized pose: not reported (it used to be,
            # with >= 30 relocalization inliers; on 7-Scenes those poses were 10-30 cm off)
            return LocalizeResult(None, "lost", int(reloc.n_inliers))
        return res
