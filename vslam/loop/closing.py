"""Loop closing: detection, geometric verification and correction (ORB-SLAM's LoopClosing thread).

After Mur-Artal et al., T-RO 2015, sec. VII, and ORB-SLAM2 (T-RO 2017, sec. VI-D):

1. **Detect.** The keyframe's BoW vector (:class:`vslam.loop.vocabulary.Vocabulary`) queries the
   :class:`KeyframeDatabase` through the :class:`LoopDetector` (its connected keyframes, sharing
   at least ``closing.connected_min_weight`` points, excluded,
   temporal consistency over ``detector.min_consistent`` keyframes). RGB-D: a single
   detection (the query's best candidate group, not yet consistent) is also verified, and accepted
   only when the query's connected keyframes confirm it (step 2; ORB-SLAM3's rule, for sequences
   of few wide-baseline keyframes where no later keyframe comes back to the place).
2. **Verify** (:func:`vslam.loop.verification.verify`): the query keyframe's descriptors are matched
   to the map points of the candidate and its covisible keyframes and (RGB-D / stereo) to those
   keyframes' keypoints with depth, keyframe by keyframe; RANSAC estimates the query's
   pose in the candidate's world, SE(3) from depth (RGB-D, stereo) or Sim(3) from the query's own
   map points (monocular, where scale drifts), refined on its inliers' reprojection errors
   (``closing.refine_ransac_pose``); guided matching by projection and robust pose
   refinement give the final inliers, at least ``closing.min_inliers`` to accept; or (RGB-D) at
   least ``closing.confirm.min_inliers`` RANSAC inliers and a connected keyframe of the query,
   verified against the same candidates, agreeing on the correction, and at least
   ``closing.confirm.min_map_inliers`` map-point inliers (:meth:`LoopCloser._confirmed`).
3. **Correct.** The matched duplicate points are fused (the candidate side's point survives, the
   query keyframes' observations are remapped), and the candidate's points are projected into the
   query's covisible keyframes and fused too (ORB-SLAM's SearchAndFuse). The essential graph
   (spanning tree: each keyframe to its predecessor; covisibility links of weight >=
   ``covisibility_edge_weight``; the loop links) is optimized with
   :func:`vslam.backend.optimize_pose_graph` (SE(3); Sim(3) for monocular; position + yaw in a
   gravity-aligned map, :func:`vslam.map.pose_graph_4dof.optimize_pose_graph_4dof`) with the segment's first
   keyframe and the loop keyframe fixed; every map point moves with its reference (first) keyframe
   (:func:`vslam.backend.correct_points`); then an optional global BA (not after a loop accepted by
   confirmation unless ``closing.global_ba_weak_loops``: its few observations do not hold the loop).

Modes (``backend.mode``, shared with local mapping):

- ``deterministic``: :meth:`LoopCloser.on_keyframe` queues and :meth:`LoopCloser.after_frame`
  processes inline after the frame (after local mapping); the same result every run.
- ``realtime``: a worker thread (lower OS priority) processes the keyframes. Detection and
  verification (~10-100 ms per keyframe) and the point fusion hold the map lock; the essential
  graph (0.2-4 s on 7-Scenes) is solved on a snapshot *without* the lock, and the write-back
  (:meth:`_apply_correction`, under the lock) applies each node's correction to the keyframe's
  current pose, moving keyframes created during the solve with the newest older node (as ORB-SLAM
  corrects keyframes inserted during a loop correction). The global BA that follows is also solved
  without the lock (:meth:`vslam.backend.local_mapping.LocalMapper.global_ba`). Every write-back
  increments ``Map.loop_epoch``, so a local BA built before it drops its stale result. Tracking is
  told through ``correction_listeners`` (the System moves the motion model's last pose by the query's
  correction) and so never waits for a solve.

Example:
    >>> closer = LoopCloser(system.map, camera, "rgbd", LoopConfig())        # doctest: +SKIP
    >>> system.add_keyframe_listener(closer.on_keyframe)                      # doctest: +SKIP
"""
from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from vslam.geometry.camera import PinholeCamera, stereo_bf
from vslam.geometry.lie import inv_se3
from vslam.loop.config import LoopConfig
from vslam.loop.detector import LoopDetector
from vslam.loop.essential_graph import EssentialGraph, build_essential_graph, write_back_corrections
from vslam.loop.loop_fusion import fuse_loop_points
from vslam.loop.segment_merging import try_merge
from vslam.loop.verification import (Features, Verified, VerifyParams, keyframe_features, keypoints_with_depth,
                                     verify)
from vslam.loop.vocabulary import BowVector, Vocabulary, load_default_vocabulary
from vslam.map.config import PoseGraphConfig
from vslam.map.database import KeyframeDatabase
from vslam.map.keyframe import KeyFrame
from vslam.map.keyframe_queue import KeyframeQueue
from vslam.map.map import Map
from vslam.map.pose_graph import load_solver, optimize_pose_graph
from vslam.map.pose_graph_4dof import optimize_pose_graph_4dof, yaw_correction

log = logging.getLogger(__name__)



@dataclass
class LoopRecord:
    """One accepted and corrected loop."""

    query_kf: int
    match_kf: int
    query_frame: int
    match_frame: int
    inliers: int
    score: float
    correction_m: float
    correction_deg: float
    scale: float
    fused_points: int
    ms: float


@dataclass
class _Prepared:
    """A verified loop whose essential graph is built and waits to be solved."""

    kf: KeyFrame
    match_id: int
    ver: Verified
    score: float
    graph: EssentialGraph
    q_group: list[int]
    c_group: list[int]
    fused: int
    four_dof: bool = False  # a gravity-aligned segment: yaw + position only


def _rot_deg(R: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))))


class LoopCloser:
    """Keyframe listener that detects, verifies and corrects loops (see the module docstring).

    Args:
        map_: the shared map.
        camera: intrinsics (``baseline`` for stereo).
        sensor: ``mono``, ``stereo`` or ``rgbd``.
        config: the root config's ``loop`` section.
        vocabulary: the BoW vocabulary (default: the packaged one).
        scale_factor: feature pyramid scale (observation sigma ``scale_factor ** octave``).
        lock: the map lock shared with tracking / local mapping.
        global_ba: callable running a full BA over the map (e.g. ``LocalMapper.global_ba``); None: none.
        pose_graph: pose-graph solver settings.
        realtime: process keyframes in a background thread (see the module docstring); else inline
            in :meth:`after_frame` (deterministic).
    """

    def __init__(self, map_: Map, camera: PinholeCamera, sensor: str, config: LoopConfig | None = None,
                 vocabulary: Vocabulary | None = None, scale_factor: float = 1.2,
                 lock: threading.RLock | None = None, global_ba: Callable[[], object] | None = None,
                 pose_graph: PoseGraphConfig | None = None, realtime: bool = False) -> None:
        self.config = config or LoopConfig()
        self.realtime = bool(realtime)
        self._queue = KeyframeQueue(self._process_timed, self.realtime, "vslam-loop-closing")
        self.map = map_
        self.camera = camera
        self.sensor = sensor
        self.scale_factor = float(scale_factor)
        self.lock = lock if lock is not None else threading.RLock()
        self.global_ba = global_ba
        self.pose_graph_config = pose_graph or PoseGraphConfig()
        self.vocabulary = vocabulary or load_default_vocabulary()
        self.database = KeyframeDatabase(self.vocabulary.n_words, self.config.database)
        self.detector = LoopDetector(self.database, self.config.detector, neighbours=self._neighbours)
        self.bf = stereo_bf(camera, sensor)
        self.bows: dict[int, BowVector] = {}
        # while one keyframe's candidates are verified: per query keyframe, its matches to each
        # candidate-side keyframe's depth keypoints (the tried groups overlap; the map is locked)
        self._extra_matches: dict[int, dict] | None = None
        self.loops: list[LoopRecord] = []
        # visual-inertial runs, until this run's IMU is initialized: a segment join between a
        # gravity-aligned and a visual segment waits for it (vslam.loop.segment_merging.try_merge)
        self.imu_pending = False
        self.rejected = 0
        self.candidates = 0
        self._last_loop_kf = -10**9
        self._times: list[float] = []
        self._t_total = 0.0
        self._n_processed = 0
        self.correction_listeners: list[Callable[[int, np.ndarray, np.ndarray], None]] = []
        # joining segments (vslam.loop.segment_merging): the records, listeners hearing (old segment,
        # new segment, S_new_old), and the local BA around the seam (``local_ba(kf_id)``, the system's)
        self.merges: list = []
        self.merge_listeners: list[Callable[[int, int, np.ndarray], None]] = []
        self.local_ba: Callable[[int], object] | None = None
        # the pose-graph solver's import (~0.3 s), at start-up rather than in the first loop correction
        self.startup_ms = {"pose_graph_solver": round(load_solver(), 1)}

    # ------------------------------------------------------------------ feeding
    def adopt_keyframes(self, database: KeyframeDatabase | None = None) -> None:
        """The map was loaded with keyframes of an earlier session: enter them in this closer's
        database (their saved BoW vectors from ``database``, else from their descriptors), so loop
        detection and relocalization find them."""
        for k in sorted(self.map.keyframes):
            kf = self.map.keyframes[k]
            if k in self.database or kf.bad:
                continue
            if database is not None and k in database:
                self.database.add(k, database.bow(k))
            elif kf.descriptors is not None and kf.descriptors.dtype == np.uint8:
                self.database.add(k, self.vocabulary.transform(kf.descriptors)[0])

    def on_keyframe(self, kf: KeyFrame) -> None:
        """Keyframe listener: queue ``kf`` (processed by :meth:`after_frame`, or by the worker
        thread in realtime mode)."""
        self._queue.put(kf.id)

    def _process_timed(self, kf_id: int) -> None:
        t0 = time.perf_counter()
        self.process(kf_id)
        self._t_total += time.perf_counter() - t0
        self._n_processed += 1

    def after_frame(self) -> None:
        """Process the queued keyframes (inline, deterministic)."""
        self._queue.run_pending()

    def finish(self) -> None:
        """Process what is queued (deterministic) or drain and join the worker (realtime)."""
        self._queue.finish()

    def _neighbours(self, kf_id: int) -> list[int]:
        return self.map.covisible(kf_id)

    def _connected(self, kf_id: int) -> list[int]:
        """Keyframes sharing at least ``closing.connected_min_weight`` points with ``kf_id`` (or its
        strongest link when none does), strongest first: ORB-SLAM's connected keyframes
        (``KeyFrame::UpdateConnections``, threshold 15). Weaker links (a few re-observed old points)
        neither hide a loop candidate from detection nor join the query side of a correction."""
        links = self.map.covisibility.get(kf_id, {})
        order = sorted(links, key=lambda k: (-links[k], k))
        strong = [k for k in order if links[k] >= self.config.closing.connected_min_weight]
        return strong if strong or not order else order[:1]

    # ------------------------------------------------------------------ one keyframe
    def process(self, kf_id: int) -> LoopRecord | None:
        """BoW, detection, verification and (if accepted) correction for keyframe ``kf_id``."""
        t0 = time.perf_counter()
        with self.lock:
            kf = self.map.keyframes.get(kf_id)
            if kf is None or kf.descriptors is None or kf.descriptors.dtype != np.uint8:
                return None
            bow, _ = self.vocabulary.transform(kf.descriptors)
            self.bows[kf_id] = bow
            cc = self.config.closing
            exclude = set(self._connected(kf_id))
            if kf_id - self._last_loop_kf < cc.min_keyframes_between or kf.bad:
                self.database.add(kf_id, bow)
                return None
            cand = self.detector.detect(kf_id, bow, covisible_ids=exclude)
            single = False
            if cand is None and cc.confirm.min_keyframes > 0 and self.sensor == "rgbd":
                cand = self.detector.last_best  # single detection: needs covisible confirmation (_verify)
                single = cand is not None
            if cand is None:
                return None
            self.candidates += 1
            prepared = None
            # the best match first, then its group (nearest ids first); at most three tries. Other
            # segments' keyframes go, in that order, to the segment join (try_merge) if no loop verifies
            same = {k.id for k in self.map.keyframes.values() if k.segment == kf.segment}
            nearest = sorted(cand.group, key=lambda i: (i != cand.match_id, abs(i - cand.match_id), i))
            order = [i for i in nearest if i not in exclude and i in same][: 1 if single else self.config.closing.max_tries]
            ver: Verified | str | None = None
            self._extra_matches = {}
            try:
                for match_id in order:
                    ver = self._verify(kf, match_id, single)
                    if ver == "implausible":
                        break  # the group agrees on a correction too large to trust
                    if ver is not None:
                        break
            finally:
                self._extra_matches = None
            if isinstance(ver, Verified):
                prepared = self._prepare_correction(kf, match_id, ver, cand.score)
            if prepared is None:
                others = [i for i in nearest if i not in exclude and i not in same and i in self.map.keyframes]
                if others and try_merge(self, kf, others) is not None:
                    return None
                self.rejected += 1
                return None
            self.detector.reset()
            self._last_loop_kf = kf_id
        # the essential graph is solved without the map lock (realtime: tracking goes on meanwhile)
        t_pg = time.perf_counter()
        graph = prepared.graph
        if prepared.four_dof:
            result = optimize_pose_graph_4dof(graph.T_init, graph.edges, graph.fixed, self.pose_graph_config)
        else:
            result = optimize_pose_graph(graph.T_init, graph.edges, fixed=graph.fixed,
                                         sim3=self.sensor == "mono", config=self.pose_graph_config)
        log.info("essential graph (%s): %d keyframes, %d edges, error %.4g -> %.4g, %.0f ms",
                 "4-DoF" if prepared.four_dof else "Sim3" if self.sensor == "mono" else "SE3", len(graph.nodes),
                 len(graph.edges), result.initial_error, result.final_error, 1e3 * (time.perf_counter() - t_pg))
        with self.lock:
            record = self._apply_correction(prepared, result)
        cc = self.config.closing
        strong = prepared.ver.n_inliers >= (cc.min_inliers_mono if self.sensor == "mono" else cc.min_inliers)
        if cc.global_ba and self.global_ba is not None and (strong or cc.global_ba_weak_loops):
            t_ba = time.perf_counter()
            self.global_ba()
            log.info("global BA after the loop: %.0f ms", 1e3 * (time.perf_counter() - t_ba))
        record.ms = round(1e3 * (time.perf_counter() - t0), 1)
        self._times.append(record.ms)
        log.info("loop closed: keyframe %d (frame %d) -> %d (frame %d), %d inliers, correction %.3f m / %.2f deg, "
                 "%.0f ms", record.query_kf, record.query_frame, record.match_kf, record.match_frame,
                 record.inliers, record.correction_m, record.correction_deg, record.ms)
        return record

    # ------------------------------------------------------------------ verification
    def features_of(self, kf: KeyFrame) -> Features:
        """:func:`vslam.loop.verification.keyframe_features` of ``kf`` in this map."""
        return keyframe_features(self.map, kf, self.camera, self.sensor)

    def _group(self, match_id: int, exclude: set[int]) -> list[int]:
        cc = self.config.closing
        group = [match_id] + [k for k in self.map.covisible(match_id, cc.candidate_neighbours) if k not in exclude]
        return [k for k in group if k in self.map.keyframes]

    def _verify_group(self, kf: KeyFrame, match_id: int) -> Verified | None:
        """:func:`verify` of ``kf`` against the candidate ``match_id`` and its covisible keyframes: their
        map points (minus those the query side observes) and, RGB-D / stereo, their keypoints with depth."""
        cc = self.config.closing
        q_side = set(self._connected(kf.id)) | {kf.id}
        group = self._group(match_id, q_side)
        pts = self.map.local_point_ids(group)
        # points the query side already observes are not loop evidence
        pts = pts[~np.isin(pts, self.map.local_point_ids([k for k in q_side if k in self.map.keyframes]))]
        ex = keypoints_with_depth(self.map, group[: 1 + cc.depth_keypoint_neighbours], self.camera) \
            if cc.match_keypoints_with_depth and self.sensor != "mono" else {}
        if ex and self._extra_matches is not None:
            ex["extra_matches"] = self._extra_matches.setdefault(kf.id, {})
        params = VerifyParams(
            ratio=cc.match_ratio, max_distance=cc.max_descriptor_distance, min_matches=cc.min_matches,
            align_threshold_m=cc.align_threshold_m, align_threshold_rel=cc.align_threshold_rel,
            search_radius_px=cc.search_radius_px, scale_factor=self.scale_factor, bf=self.bf,
            seed=kf.id, refine_ransac=cc.refine_ransac_pose,
            guided_max_distance=cc.guided_max_descriptor_distance, guided_ratio=cc.guided_ratio,
            min_search_radius_px=cc.min_search_radius_px)
        return verify(self.features_of(kf), self.map.points, pts, self.camera, self.sensor, params, **ex)

    def _verify(self, kf: KeyFrame, match_id: int, single: bool = False) -> Verified | str | None:
        """Verify the candidate; accepted with ``min_inliers`` map-point inliers, or when
        :meth:`_confirmed`. A ``single`` detection (one temporal consistency has not confirmed yet) is
        accepted only through :meth:`_confirmed`, and only when it has fewer than ``min_inliers``
        map-point inliers: a loop with that many is in a well-mapped place, where the following
        keyframes will find it again and temporal consistency (ORB-SLAM2's rule) decides as before.
        Returns ``"implausible"`` for a correction beyond the ``max_correction`` bounds."""
        cc = self.config.closing
        match = self.map.keyframes[match_id]
        if match.segment != kf.segment or match.bad:
            return None
        ver = self._verify_group(kf, match_id)
        need = cc.min_inliers_mono if self.sensor == "mono" else cc.min_inliers
        strong = ver is not None and ver.n_inliers >= need
        if single and strong:
            log.debug("single loop candidate %d -> %d (%d inliers) left to temporal consistency", kf.id, match_id,
                      ver.n_inliers)
            return None
        if ver is None or not (strong or self._confirmed(kf, match_id, ver)):
            log.debug("loop candidate %d -> %d rejected: %s inliers", kf.id, match_id,
                      None if ver is None else (ver.n_ransac, ver.n_inliers))
            return None
        dT = ver.T_world_cam @ kf.T_cam_world
        deg, dist = _rot_deg(dT[:3, :3]), float(np.linalg.norm(ver.T_world_cam[:3, 3] - kf.T_world_cam[:3, 3]))
        if deg > cc.max_correction_deg or (self.sensor != "mono" and dist > cc.max_correction_m):
            log.info("loop candidate %d -> %d rejected: implausible correction %.2f m / %.1f deg",
                     kf.id, match_id, dist, deg)
            return "implausible"
        return ver

    def _confirmed(self, kf: KeyFrame, match_id: int, ver: Verified) -> bool:
        """Weak-but-real loops of sparse keyframe sequences (RGB-D): accept a verification below
        ``min_inliers`` when it has at least ``confirm.min_inliers`` inliers (RANSAC, with the
        keypoints with depth, or after refinement) and at least ``confirm.min_keyframes`` of the
        query's connected keyframes, verified independently against the same candidate group, agree on
        the query's corrected pose within ``confirm.max_m`` / ``confirm.max_deg``. After ORB-SLAM3's
        ``DetectCommonRegionsFromBoW`` (Campos et al., T-RO 2021, sec. VI-A): a candidate is confirmed
        by the query's covisible keyframes instead of waiting for later keyframes, which a sequence
        of few, wide-baseline keyframes may never provide. Connected keyframes have nearly the same
        drift, so their corrections agree on a true loop; a false match (repeated structure, chance)
        gives unrelated corrections. Not for stereo: the 3D-3D RANSAC threshold grows with depth
        squared (RGB-D noise), so on far outdoor points (KITTI, median depth ~15 m) it is metres wide
        and RANSAC counts 100+ "inliers" for wrong poses; only the agreement test rejected those."""
        cc = self.config.closing
        if cc.confirm.min_keyframes <= 0 or self.sensor != "rgbd":
            return False
        if max(ver.n_inliers, ver.n_ransac) < cc.confirm.min_inliers or ver.n_inliers < cc.confirm.min_map_inliers:
            return False
        T_cam_world_q = inv_se3(ver.T_world_cam)  # the query's corrected pose
        agree = 0
        for k in self._connected(kf.id)[: cc.confirm.neighbours]:
            other = self.map.keyframes.get(k)
            if other is None or other.bad or other.descriptors is None or k == match_id:
                continue
            v = self._verify_group(other, match_id)
            if v is None or max(v.n_inliers, v.n_ransac) < cc.confirm.min_inliers:
                continue
            # the query moved by the neighbour's correction vs by its own
            D = T_cam_world_q @ v.T_world_cam @ other.T_cam_world @ kf.T_world_cam
            if np.linalg.norm(D[:3, 3]) <= cc.confirm.max_m and _rot_deg(D[:3, :3]) <= cc.confirm.max_deg:
                agree += 1
            log.debug("loop %d -> %d: keyframe %d corrects %.3f m / %.2f deg apart (%d/%d inliers)", kf.id,
                      match_id, k, np.linalg.norm(D[:3, 3]), _rot_deg(D[:3, :3]), v.n_ransac, v.n_inliers)
            if agree >= cc.confirm.min_keyframes:
                log.info("loop candidate %d -> %d (%d/%d inliers) confirmed by %d connected keyframe(s)", kf.id,
                         match_id, ver.n_ransac, ver.n_inliers, agree)
                return True
        return False

    # ------------------------------------------------------------------ correction
    def _prepare_correction(self, kf: KeyFrame, match_id: int, ver: Verified, score: float) -> _Prepared:
        """Under the map lock: fuse the loop's duplicated points and build the essential graph
        (a snapshot of the keyframe poses; solved by :meth:`process` without the lock)."""
        cc = self.config.closing
        in_segment = {k.id for k in self.map.keyframes.values() if k.segment == kf.segment}
        # the query side: the query and its covisible keyframes, moved by the loop's correction; in a
        # gravity-aligned segment its yaw + translation only (roll / pitch are observed by the IMU)
        four_dof = self.map.segment_gravity_aligned(kf.segment)
        S_corr = yaw_correction(kf.T_world_cam, ver.T_world_cam) if four_dof else ver.S_world_cam @ kf.T_cam_world
        q_group = [kf.id] + [k for k in self._connected(kf.id) if k in in_segment and k != match_id]
        c_group = self._group(match_id, set(q_group))
        S_init = {k: S_corr @ self.map.keyframes[k].T_world_cam for k in q_group}
        fused = fuse_loop_points(self.map, self.camera, self.sensor, cc, kf, ver, q_group, c_group, S_init)
        graph = build_essential_graph(self.map, kf.segment, match_id, q_group, c_group, S_init,
                                      cc.covisibility_edge_weight, cc.loop_edge_information)
        return _Prepared(kf, match_id, ver, score, graph, q_group, c_group, fused, four_dof)

    def _apply_correction(self, p: _Prepared, result) -> LoopRecord:
        """Under the map lock: write the essential graph's result back
        (:func:`vslam.loop.essential_graph.write_back_corrections`: each keyframe moves by its node's
        correction applied to its *current* pose, so a local BA that moved it during the solve is
        kept; keyframes created during the solve take the correction of the newest older node, as
        ORB-SLAM2 corrects keyframes inserted during a loop correction; points move with their
        reference keyframe). In deterministic mode nothing changes during the solve and this is the
        plain write-back."""
        kf, match_id, ver = p.kf, p.match_id, p.ver
        T_q_before = kf.T_world_cam.copy()
        write_back_corrections(self.map, kf.segment, p.graph.nodes, p.graph.T_before, result.S_world_cam)
        self.map.loop_epoch += 1  # local BAs built before this write-back are stale
        for k in set(p.q_group) | set(p.c_group):
            self.map.update_covisibility(k)
        for cb in self.correction_listeners:
            cb(kf.id, T_q_before, kf.T_world_cam.copy())
        dT = ver.T_world_cam @ inv_se3(T_q_before)
        rec = LoopRecord(
            query_kf=kf.id, match_kf=match_id, query_frame=kf.frame_index,
            match_frame=self.map.keyframes[match_id].frame_index, inliers=ver.n_inliers, score=round(p.score, 3),
            correction_m=round(float(np.linalg.norm(ver.T_world_cam[:3, 3] - T_q_before[:3, 3])), 4),
            correction_deg=round(_rot_deg(dT[:3, :3]), 3), scale=round(ver.scale, 4), fused_points=p.fused, ms=0.0,
        )
        self.loops.append(rec)
        return rec

    # ------------------------------------------------------------------ stats
    def loop_list(self) -> list[list[int]]:
        """``[[query_frame_index, matched_frame_index, inliers], ...]`` of the accepted loops."""
        return [[r.query_frame, r.match_frame, r.inliers] for r in self.loops]

    def stats(self) -> dict:
        return {
            "loops": self.loop_list(), "candidates": self.candidates, "rejected": self.rejected,
            "failed": self._queue.failed, "mode": "realtime" if self.realtime else "deterministic",
            "details": [r.__dict__.copy() for r in self.loops],
            "loop_ms_mean": round(float(np.mean(self._times)), 1) if self._times else 0.0,
            "ms_per_keyframe": round(1e3 * self._t_total / max(self._n_processed, 1), 2),
            "keyframes_processed": self._n_processed,
            "merges": [m.to_json() for m in self.merges],
        }
