"""Local mapping: windowed bundle adjustment after each keyframe, culling, and a final global BA.

After ORB-SLAM's LocalMapping thread (Mur-Artal et al., T-RO 2015, Sec. VI; ORB-SLAM2, T-RO 2017,
Sec. VI-B):

1. **Window.** The new keyframe, the ``window_size`` most recent keyframes of its map segment and
   its ``covisible_keyframes`` strongest covisibility neighbours (links to non-adjacent keyframes)
   are optimized, with every live map point they observe.
1b. **Fuse** (``fusion.enabled``, needs descriptors): the window's points are projected into the new
   keyframe and the new keyframe's points into the window; chi-square-checked descriptor matches add
   observations or merge duplicate points (ORB-SLAM2 SearchInNeighbors), so keyframes share points.
   Monocular maps skip it unless ``fusion.mono`` (measured on KITTI 07: it raised the ATE on every clip).
2. **Gauge.** Keyframes outside the window that observe those points enter the problem with their
   poses held constant; the first keyframe of the segment is always constant. Monocular problems
   hold at least two keyframes constant so the scale is fixed too, and leave out the points fewer
   than ``mono.min_observations`` keyframes see (two-view points: their depth drifts outwards in BA).
   Stereo / RGB-D problems leave out points with no depth or disparity whose rays span less than
   ``depthless_min_parallax_deg`` (their depth is unobservable).
3. **Solve** with :func:`vslam.backend.local_bundle_adjustment` (robust pass, chi-square outlier
   removal, refinement) and write poses (``kf.T_world_cam``) and points back into the map.
4. **Cull.** Observations failing the chi-square test are removed (``kf.point_ids[i] = -1``);
   points left without observations die; recent points that too few keyframes re-observed die
   (ORB-SLAM's MapPointCulling); optionally redundant keyframes (>= ``cull.redundant_ratio`` of their points
   seen by >= 3 other keyframes, ORB-SLAM's KeyFrameCulling) are flagged ``bad``. A culled keyframe
   stays in ``map.keyframes`` (frames reference it) and its pose follows its parent keyframe (the
   strongest covisible one) rigidly from then on.

Modes: ``deterministic`` queues keyframes and processes them inline when :meth:`LocalMapper.after_frame`
is called (the same result every run); ``parallel`` snapshots the problem at the end of the keyframe's
frame, solves it in a worker (a child process, or a thread: ``parallel_worker``) while the next
frames are tracked, and writes it back at the end of the ``lag_frames``-th frame after (or of the
frame bringing the next keyframe, if sooner), waiting for the worker if need be: the result
depends on frame counts only, so every run is the same too. Keyframes made between snapshot and
write-back follow the newest optimized keyframe (as after a global BA), and loop closing sees a
keyframe after its write-back (:class:`vslam.map.keyframe_queue.LaggedQueue`); ``realtime`` processes them in a background thread, taking
``lock`` only to snapshot the problem and to write the result back, so tracking (which holds the
same lock while it touches the map) never waits for a solve. When keyframes arrive faster than
BAs finish, only the newest waiting keyframe is optimized (its window covers the others).

Example:
    >>> mapper = LocalMapper(system.map, camera, "rgbd", BackendConfig())     # doctest: +SKIP
    >>> system.add_keyframe_listener(mapper.on_keyframe)                       # doctest: +SKIP
"""
from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from vslam.backend.bundle_adjustment import global_bundle_adjustment, local_bundle_adjustment
from vslam.backend.config import BackendConfig, LocalBAConfig
from vslam.backend.culling import Culling
from vslam.backend.fuse import NeighbourFusion
from vslam.backend.local_problem import LocalProblemBuilder, ProblemContext, max_parallax_deg
from vslam.backend.map_writeback import PointWriteback
from vslam.backend.problem import BAProblem, BAResult
from vslam.geometry.camera import PinholeCamera
from vslam.geometry.lie import inv_se3
from vslam.map.keyframe_queue import KeyframeQueue, LaggedQueue
from vslam.map.keyframe import KeyFrame
from vslam.map.map import Map
from vslam.map.new_points import KeyframeMapping, NewPointsParams

__all__ = ["LocalMapper", "max_parallax_deg"]

LOG = logging.getLogger(__name__)


@dataclass
class _Job:
    """One local BA between its snapshot and its write-back: the problem, its context, the loop
    epoch it was built in, the dense links appended, the keyframes that existed (parallel mode) and
    the time the snapshot took."""

    kf_id: int
    problem: BAProblem
    ctx: ProblemContext
    epoch: int
    n_links: int
    known: set[int] | None
    prepare_s: float


def solve_job(config: LocalBAConfig, job: _Job) -> BAResult | str:
    """The solve alone: touches only ``job`` (the worker's part in parallel mode, in a thread or a
    child process); a failure comes back as its message."""
    try:
        return local_bundle_adjustment(job.problem, config)
    except Exception as exc:
        return f"{type(exc).__name__}: {exc}"


def warm_worker() -> None:
    """Parallel mode, process worker: load the compiled kernels in the child before the first job."""
    from vslam.backend import schur_kernels

    schur_kernels.warm()


class LocalMapper:
    """Windowed BA + culling after each keyframe, global BA on demand (see the module docstring).

    Args:
        map_: the shared map.
        camera: intrinsics (with ``baseline`` for stereo).
        sensor: ``mono``, ``stereo`` or ``rgbd``.
        config: the backend's :class:`~vslam.backend.config.BackendConfig` (default: its defaults).
        scale_factor: feature pyramid scale; an observation at octave ``o`` has sigma ``scale_factor ** o`` px.
        lock: the map lock shared with tracking (realtime mode); a private one when None.
        new_points: settings of the point creation and culling run on each keyframe as it arrives
            (:class:`vslam.map.new_points.KeyframeMapping`); None: none.
    """

    #: the process worker's solve (parallel mode): a module-level ``f(LocalBAConfig, job)``, picklable
    job_solver = staticmethod(solve_job)

    def __init__(self, map_: Map, camera: PinholeCamera, sensor: str, config: BackendConfig | None = None,
                 scale_factor: float = 1.2, lock: threading.RLock | None = None,
                 new_points: NewPointsParams | None = None) -> None:
        self.config = config if config is not None else BackendConfig()
        self.keyframe_mapping = KeyframeMapping(map_, new_points) if new_points is not None else None
        self.map = map_
        self.camera = camera
        self.sensor = sensor
        self.scale_factor = float(scale_factor)
        self.lock = lock if lock is not None else threading.RLock()
        self._parallel = self.config.mode == "parallel"
        if self._parallel:
            import functools

            worker = self.config.parallel_worker
            solve = functools.partial(self.job_solver, self.config.local) if worker == "process" else self._solve
            self._queue = LaggedQueue(self._prepare, solve, self._finish, self._settled, self.config.lag_frames,
                                      "vslam-local-ba", worker=worker, warm=warm_worker)
        else:
            self._queue = KeyframeQueue(self.process, self.config.mode == "realtime", "vslam-local-mapping",
                                        newest_only=True)
        # parallel mode: called as ``cb(keyframe)`` once a keyframe's local BA is in the map (the System
        # runs loop closing there, after local mapping as in deterministic mode)
        self.settled_listeners: list = []
        self._stop = False
        self._times: list[float] = []
        self._solve_times: list[float] = []
        self.counts = {"local_ba_calls": 0, "local_ba_skipped": 0, "outlier_observations": 0, "fused_points": 0,
                       "culled_points": 0, "culled_keyframes": 0, "failed": 0}
        self.global_ba_result: dict | None = None
        # called as ``cb(kf_id, T_world_kf_before, T_world_kf_after)`` when the newest keyframe moves
        # (System re-anchors the tracker's motion model on it, ORB-SLAM's UpdateLastFrame)
        self.correction_listeners: list = []
        # RGB-D: {kf_id: DenseLink} from the tracker's dense alignments, constraints in local BA
        # (vslam.backend.dense_links; filled by the System when frontend.dense.links is on)
        self.dense_links: dict = {}
        self.problems = LocalProblemBuilder(map_, camera, sensor, self.config, self.scale_factor)
        self.fusion = NeighbourFusion(map_, camera, sensor, self.config, self.scale_factor, self.problems.window,
                                      self.counts)
        self.culling = Culling(map_, self.config, self.counts)
        mono = self.config.mono
        self.writeback = PointWriteback(map_, camera, mono.retriangulate_max_reproj_px, mono.retriangulate_min_parallax_deg)

    # ------------------------------------------------------------------ feeding
    def on_keyframe(self, kf: KeyFrame) -> None:
        """Keyframe listener: new points (monocular) and point culling right away, in the
        tracking thread, so the next frame tracks them (:mod:`vslam.map.new_points`); then queue
        ``kf`` for local BA."""
        if self.keyframe_mapping is not None:
            with self.lock:
                self.keyframe_mapping.on_keyframe(kf)
        if not self.config.local_ba:
            return
        self._queue.put(kf.id)

    def after_frame(self) -> None:
        """Deterministic mode: process the keyframes queued while tracking this frame (inline);
        parallel mode: write back the local BA whose lag is over, hand the new keyframe's to the worker."""
        self._queue.run_pending()

    def finish(self) -> None:
        """Flush: process everything queued (deterministic) or join the worker (realtime)."""
        self._queue.finish()

    # ------------------------------------------------------------------ one local BA
    def process(self, kf_id: int) -> BAResult | None:
        """Windowed BA around keyframe ``kf_id``, write-back and culling."""
        job = self._prepare(kf_id)
        if job is None:
            return None
        return self._finish(job, self._solve(job))

    def _prepare(self, kf_id: int) -> _Job | None:
        """Under the lock: fuse the neighbours, build the window problem (a snapshot: its arrays are
        copies, so :meth:`_solve` may run in another thread while tracking edits the map)."""
        t0 = time.perf_counter()
        with self.lock:
            if self.config.fusion.enabled and (self.sensor != "mono" or self.config.fusion.mono):
                self.fusion.fuse_neighbours(kf_id)
            built = self.problems.build_local(kf_id)
            epoch = self.map.loop_epoch
            n_links = 0
            if built is not None and self.dense_links:
                from vslam.backend.dense_links import add_dense_links

                linked, n_links = add_dense_links(built[0], self.dense_links,
                                                  min_depth=self.config.dense_link_min_depth)
                built = (linked, built[1])
            known = set(self.map.keyframes) if self._parallel else None
        if built is None:
            return None
        return _Job(kf_id, built[0], built[1], epoch, n_links, known, time.perf_counter() - t0)

    def _solve(self, job: _Job) -> BAResult | str:
        return solve_job(self.config.local, job)

    def _finish(self, job: _Job, result: BAResult | str) -> BAResult | None:
        """Under the lock: write the result back and cull. Parallel mode: keyframes made after the
        snapshot follow the newest optimized keyframe of their segment (as after a global BA)."""
        if isinstance(result, str):  # GeometryError or a singular system: keep the map as it is
            self.counts["failed"] += 1
            LOG.warning("local BA on keyframe %d failed: %s", job.kf_id, result)
            return None
        t0 = time.perf_counter()
        kf_id, problem, ctx = job.kf_id, job.problem, job.ctx
        if job.n_links:
            from vslam.backend.dense_links import strip_dense_links

            problem, result = strip_dense_links(problem, result, job.n_links)
        with self.lock:
            if self.map.loop_epoch != job.epoch:  # realtime: a loop correction moved the map meanwhile
                self.counts["stale_dropped"] = self.counts.get("stale_dropped", 0) + 1
                LOG.info("local BA on keyframe %d dropped: a loop correction moved the map meanwhile", kf_id)
                return None
            before = None
            if job.known is not None and len(self.map.keyframes) > len(job.known):
                before = {k: self.map.keyframes[k].T_world_cam.copy() for k in result.kf_ids.tolist()
                          if k in self.map.keyframes}
            self._apply(problem, result, ctx)
            if before is not None:
                self._propagate_to_new_keyframes(before, job.known)
            self.culling.cull_points(kf_id)
            if self.config.cull.keyframes:
                self.culling.cull_keyframes(kf_id)
            self._update_bad_keyframes()
        self._times.append(job.prepare_s + time.perf_counter() - t0 + (0.0 if self._parallel else result.time_s))
        self._solve_times.append(result.time_s)
        self.counts["local_ba_calls"] += 1
        LOG.debug("local BA kf %d: %d kfs (%d fixed), %d pts, rms %.2f -> %.2f px, %.0f ms", kf_id,
                  problem.num_keyframes, len(ctx.fixed), problem.num_points, result.initial_rms_px,
                  result.final_rms_px, 1e3 * result.time_s)
        return result

    def _settled(self, kf_id: int) -> None:
        """Parallel mode: keyframe ``kf_id``'s local mapping is in the map (loop closing plugs in here)."""
        kf = self.map.keyframes.get(kf_id)
        if kf is not None:
            for cb in self.settled_listeners:
                cb(kf)

    def _window(self, kf: KeyFrame) -> tuple[list[int], list[int]]:
        """``(optimized keyframe ids, constant keyframe ids)`` of the local BA around ``kf``."""
        return self.problems.window(kf)

    def _problem(self, var_ids: list[int], fixed_ids: list[int], pts: np.ndarray,
                 new_kf: int) -> tuple[BAProblem, ProblemContext] | None:
        return self.problems.build(var_ids, fixed_ids, pts, new_kf)

    def _set_bad(self, kf: KeyFrame) -> None:
        self.culling.set_bad(kf)

    def _update_bad_keyframes(self) -> None:
        self.culling.update_bad_keyframes()

    def _retriangulate_left_out(self, pt: np.ndarray, kf: np.ndarray, uv: np.ndarray,
                                corrections: dict[int, np.ndarray]) -> None:
        self.writeback.retriangulate_left_out(pt, kf, uv, corrections)


    # ------------------------------------------------------------------ write-back and culling
    def _apply(self, problem: BAProblem, result: BAResult, ctx: ProblemContext) -> None:
        """Poses, points and outlier observations back into the map (under the lock)."""
        store = self.map.points
        if len(store) < ctx.n_rows:
            LOG.info("map compacted during local BA: result dropped")
            return
        fixed = np.isin(result.kf_ids, ctx.fixed)
        finite = np.isfinite(result.T_world_cam).all(axis=(1, 2))  # once, not per keyframe
        newest = self._newest_kf()  # (the keyframes do not change during this loop)
        moved = None
        corrections: dict[int, np.ndarray] = {}
        for kid, T, f, ok in zip(result.kf_ids.tolist(), result.T_world_cam, fixed.tolist(), finite.tolist()):
            kf = self.map.keyframes.get(kid)
            if kf is not None and not f and ok:
                if kid == newest:
                    moved = (kid, kf.T_world_cam.copy(), T.copy())
                if ctx.left_out is not None:
                    corrections[kid] = T @ inv_se3(kf.T_world_cam)
                kf.T_world_cam = T.copy()
        if ctx.left_out is not None and len(ctx.left_out[0]) and corrections:
            if self.config.mono.left_out == "retriangulate":
                self._retriangulate_left_out(*ctx.left_out, corrections)
            else:
                self.writeback.transport_left_out(ctx.left_out[0], corrections)
        if moved is not None:
            for cb in self.correction_listeners:
                cb(*moved)
        alive = store.alive[result.pt_ids]
        good_X = alive & np.all(np.isfinite(result.X_world), axis=1)
        store.position[result.pt_ids[good_X]] = result.X_world[good_X]
        self.writeback.update_normals(problem, result, good_X)
        out = ~result.inlier_mask
        if not np.any(out):
            return
        o_kf, o_pt, o_idx = problem.obs_kf[out], problem.obs_pt[out], ctx.obs_idx[out]
        removed = []
        for kid in np.unique(o_kf).tolist():
            kf = self.map.keyframes.get(kid)
            if kf is None:
                continue
            m = o_kf == kid
            idx, pid = o_idx[m], o_pt[m]
            still = kf.point_ids[idx] == pid  # realtime: tracking may have changed it meanwhile
            kf.point_ids[idx[still]] = -1
            removed.append(pid[still])
        if removed:
            r = np.concatenate(removed)
            np.subtract.at(store.n_obs, r, 1)
            self.counts["outlier_observations"] += len(r)

    def _newest_kf(self) -> int:
        return max(self.map.keyframes) if self.map.keyframes else -1


    # ------------------------------------------------------------------ global BA
    def global_ba(self) -> BAResult | None:
        """Full BA over every good keyframe and live point; each segment's first keyframe (two for
        monocular, also fixing the scale) is constant.

        The problem is snapshot under the map lock and solved without it (in realtime mode tracking
        goes on meanwhile); the write-back takes the lock again, and keyframes created during the
        solve (and the points they created) move with the newest optimized keyframe of their segment
        (ORB-SLAM2's RunGlobalBundleAdjustment propagation through the spanning tree). A result made
        stale by a loop correction during the solve is dropped."""
        if self._parallel:
            self._queue.settle()  # no local BA in flight during a global one
        with self.lock:
            kfs = [k for k in self.map.keyframes.values() if not k.bad]
            if len(kfs) < 2:
                return None
            fixed: list[int] = []
            for seg in sorted({k.segment for k in kfs}):
                ids = sorted(k.id for k in kfs if k.segment == seg)
                fixed += ids[: (2 if self.sensor == "mono" else 1)]
            var = [k.id for k in sorted(kfs, key=lambda k: k.id) if k.id not in fixed]
            pts = self.map.local_point_ids([k.id for k in kfs])
            built = self._problem(var, fixed, pts, -1)
            if built is None:
                return None
            problem, ctx = built
            n_links = 0
            if self.dense_links:
                from vslam.backend.dense_links import add_dense_links

                problem, n_links = add_dense_links(problem, self.dense_links,
                                                   min_depth=self.config.dense_link_min_depth)
            epoch = self.map.loop_epoch
            known = set(self.map.keyframes)
        t0 = time.perf_counter()
        try:
            result = global_bundle_adjustment(problem, self.config.global_ba)
        except Exception as exc:
            LOG.warning("global BA failed: %s", exc)
            return None
        if n_links:
            from vslam.backend.dense_links import strip_dense_links

            problem, result = strip_dense_links(problem, result, n_links)
        if not self._write_back_global(problem, result, ctx, epoch, known, "global BA"):
            return None
        self.counts["global_ba_calls"] = self.counts.get("global_ba_calls", 0) + 1
        self.global_ba_result = {
            "keyframes": problem.num_keyframes, "points": problem.num_points,
            "observations": problem.num_observations, "initial_rms_px": round(result.initial_rms_px, 4),
            "final_rms_px": round(result.final_rms_px, 4), "iterations": result.iterations,
            "ms": round(1e3 * (time.perf_counter() - t0), 1),
        }
        LOG.info("global BA: %s", self.global_ba_result)
        return result

    def _write_back_global(self, problem, result, ctx, epoch: int, known: set[int], what: str,
                           then: Callable[[], None] | None = None) -> bool:
        """Under the lock, write a global solve (global BA, full VI-BA) back to the map, unless a loop
        correction moved the map since its snapshot (``epoch``): poses and points, keyframes created
        meanwhile (not in ``known``) moved with their segment, bad keyframes marked, ``then()`` (more
        state to store), and ``Map.loop_epoch`` bumped (local BAs built before are stale). False when dropped."""
        with self.lock:
            if self.map.loop_epoch != epoch:
                LOG.info("%s dropped: a loop correction moved the map during the solve", what)
                return False
            before = {kid: self.map.keyframes[kid].T_world_cam.copy() for kid in result.kf_ids.tolist()
                      if kid in self.map.keyframes}
            self._apply(problem, result, ctx)
            self._propagate_to_new_keyframes(before, known)
            self._update_bad_keyframes()
            if then is not None:
                then()
            self.map.loop_epoch += 1
        return True

    def _propagate_to_new_keyframes(self, before: dict[int, np.ndarray], known: set[int]) -> None:
        """Keyframes missing from a global BA (created during its solve) take the correction
        ``T_after T_before^-1`` of the newest optimized keyframe of their segment, and so do the
        points they created. No-op in deterministic mode (nothing is created during a solve)."""
        new = sorted(k for k in self.map.keyframes if k not in known)
        if not new:
            return
        store = self.map.points
        n = len(store)
        moved = None
        for kid in new:
            kf = self.map.keyframes[kid]
            older = [k for k in before if self.map.keyframes[k].segment == kf.segment and k < kid]
            if not older:
                continue
            ref = max(older)
            # the general inverse: in parallel mode these snapshots are not always exactly rigid
            # (inv_se3 here made the parallel cabinet run diverge; to be understood)
            D = self.map.keyframes[ref].T_world_cam @ np.linalg.inv(before[ref])
            T_old = kf.T_world_cam.copy()
            kf.T_world_cam = D @ T_old
            ids = np.flatnonzero(store.alive[:n] & (store.first_kf[:n] == kid))
            store.position[ids] = store.position[ids] @ D[:3, :3].T + D[:3, 3]
            moved = (kid, T_old, kf.T_world_cam.copy())
        if moved is not None and moved[0] == self._newest_kf():
            for cb in self.correction_listeners:
                cb(*moved)

    # ------------------------------------------------------------------ stats
    def stats(self) -> dict:
        t = np.asarray(self._times)
        out: dict = dict(self.counts)
        out["local_ba_skipped"] += getattr(self._queue, "skipped", 0)  # realtime: keyframes that piled up
        out["failed"] += self._queue.failed
        out["mode"] = self.config.mode
        if self._parallel:
            out["lag_frames"] = self.config.lag_frames
            out["local_ba_wait_ms_total"] = round(1e3 * self._queue.wait_s, 1)
        out["local_ba_ms_mean"] = round(1e3 * float(t.mean()), 2) if len(t) else 0.0
        out["local_ba_ms_median"] = round(1e3 * float(np.median(t)), 2) if len(t) else 0.0
        out["local_ba_ms_total"] = round(1e3 * float(t.sum()), 1)
        out["local_ba_solver_ms_mean"] = round(1e3 * float(np.mean(self._solve_times)), 2) if self._solve_times else 0.0
        if self.global_ba_result is not None:
            out["global_ba"] = self.global_ba_result  # the last one (final_ba, or a loop closure's)
        return out

