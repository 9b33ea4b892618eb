"""Local mapping: windowed bundle adjustment after each keyframe, culling, and a final global BA.

After ORB-SLAM's LocalMapping thread (Mur-Artal et al., T-RO 2015, Sec. VI; ORB-SLAM2, T-RO 2017,
Sec. VI-B):

1. **Window.** The new keyframe, the ``window_size`` most recent keyframes of its map segment and
   its ``covisible_keyframes`` strongest covisibility neighbours (links to non-adjacent keyframes)
   are optimized, with every live map point they observe.
1b. **Fuse** (``fuse``, needs descriptors): the window's points are projected into the new
   keyframe and the new keyframe's points into the window; chi-square-checked descriptor matches add
   observations or merge duplicate points (ORB-SLAM2 SearchInNeighbors), so keyframes share points.
   Monocular maps skip it unless ``fuse_mono`` (measured on KITTI 07: it raised the ATE on every clip).
2. **Gauge.** Keyframes outside the window that observe those points enter the problem with their
   poses held constant; the first keyframe of the segment is always constant. Monocular problems
   hold at least two keyframes constant so the scale is fixed too, and leave out the points fewer
   than ``mono_min_observations`` keyframes see (two-view points: their depth drifts outwards in BA).
   Stereo / RGB-D problems leave out points with no depth or disparity whose rays span less than
   ``depthless_min_parallax_deg`` (their depth is unobservable).
3. **Solve** with :func:`vslam.backend.local_bundle_adjustment` (robust pass, chi-square outlier
   removal, refinement) and write poses (``kf.T_world_cam``) and points back into the map.
4. **Cull.** Observations failing the chi-square test are removed (``kf.point_ids[i] = -1``);
   points left without observations die; recent points that too few keyframes re-observed die
   (ORB-SLAM's MapPointCulling); optionally redundant keyframes (>= ``redundant_ratio`` of their points
   seen by >= 3 other keyframes, ORB-SLAM's KeyFrameCulling) are flagged ``bad``. A culled keyframe
   stays in ``map.keyframes`` (frames reference it) and its pose follows its parent keyframe (the
   strongest covisible one) rigidly from then on.

Modes: ``deterministic`` queues keyframes and processes them inline when :meth:`LocalMapper.after_frame`
is called (the same result every run); ``realtime`` processes them in a background thread, taking
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

import numpy as np

from vslam.backend.bundle_adjustment import global_bundle_adjustment, local_bundle_adjustment
from vslam.backend.config import BackendConfig
from vslam.backend.problem import BAProblem, BAResult
from vslam.geometry.camera import PinholeCamera
from vslam.map.fusion import apply_remap, new_remap
from vslam.map.keyframe_queue import KeyframeQueue
from vslam.map.keyframe import KeyFrame
from vslam.map.mappoint import unique_ids
from vslam.map.map import Map

LOG = logging.getLogger(__name__)


@dataclass
class _Context:
    """What :meth:`LocalMapper._apply` needs besides the problem: keypoint index of each observation,
    which keyframes were constant, and the store size (to detect a compaction in between)."""

    obs_idx: np.ndarray
    fixed: np.ndarray
    n_rows: int
    new_kf: int
    left_out: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # monocular points kept out: (pt, kf, uv) per observation


def max_parallax_deg(centres: np.ndarray, X_world: np.ndarray, point: np.ndarray, n_points: int) -> np.ndarray:
    """Per point, the largest angle (degrees) between its first observation's viewing ray and the
    others (a lower bound of the largest pairwise parallax, at least half of it; 0 for one observation).

    ``centres (M, 3)``: the observing camera centre per observation, ``X_world (M, 3)``: the point per
    observation, ``point (M,)``: point row of each observation in ``0 .. n_points - 1``. Parallax as
    in ORB-SLAM2's triangulation test (Mur-Artal & Tardos 2017: ``cos`` of the ray angle > 0.9998 is
    too little), vectorized over observations.
    """
    ray = X_world - centres
    ray /= np.maximum(np.linalg.norm(ray, axis=1, keepdims=True), 1e-12)
    first = np.full(n_points, -1, np.int64)
    first[point[::-1]] = np.arange(len(point))[::-1]  # the last write wins: the first observation
    cos = np.einsum("ij,ij->i", ray, ray[first[point]])
    min_cos = np.ones(n_points)
    np.minimum.at(min_cos, point, cos)
    return np.degrees(np.arccos(np.clip(min_cos, -1.0, 1.0)))


def _segment_keyframes(map_: Map, segment: int) -> list[KeyFrame]:
    return [k for k in map_.keyframes.values() if k.segment == segment and not k.bad]


class LocalMapper:
    """Windowed BA + culling after each keyframe, global BA on demand (see the module docstring).

    Args:
        map_: the shared map.
        camera: intrinsics (with ``baseline`` for stereo).
        sensor: ``mono``, ``stereo`` or ``rgbd``.
        config: the backend's :class:`~vslam.backend.config.BackendConfig` (default: its defaults).
        scale_factor: feature pyramid scale; an observation at octave ``o`` has sigma ``scale_factor ** o`` px.
        lock: the map lock shared with tracking (realtime mode); a private one when None.
    """

    def __init__(self, map_: Map, camera: PinholeCamera, sensor: str, config: BackendConfig | None = None,
                 scale_factor: float = 1.2, lock: threading.RLock | None = None) -> None:
        self.config = config if config is not None else BackendConfig()
        self.map = map_
        self.camera = camera
        self.sensor = sensor
        self.scale_factor = float(scale_factor)
        self.lock = lock if lock is not None else threading.RLock()
        self._queue = KeyframeQueue(self.process, self.config.mode == "realtime", "vslam-local-mapping",
                                    newest_only=True)
        self._stop = False
        self._times: list[float] = []
        self._solve_times: list[float] = []
        self._culled_upto: dict[int, int] = {}
        self.counts = {"local_ba_calls": 0, "local_ba_skipped": 0, "outlier_observations": 0, "fused_points": 0,
                       "culled_points": 0, "culled_keyframes": 0, "failed": 0}
        self.global_ba_result: dict | None = None
        # called as ``cb(kf_id, T_world_kf_before, T_world_kf_after)`` when the newest keyframe moves
        # (System re-anchors the tracker's motion model on it, ORB-SLAM's UpdateLastFrame)
        self.correction_listeners: list = []
        # RGB-D: {kf_id: DenseLink} from the tracker's dense alignments, constraints in local BA
        # (vslam.backend.dense_links; filled by the System when frontend.dense.links is on)
        self.dense_links: dict = {}

    # ------------------------------------------------------------------ feeding
    def on_keyframe(self, kf: KeyFrame) -> None:
        """Keyframe listener: queue ``kf`` for local mapping."""
        if not self.config.local_ba:
            return
        self._queue.put(kf.id)

    def after_frame(self) -> None:
        """Deterministic mode: process the keyframes queued while tracking this frame (inline)."""
        self._queue.run_pending()

    def finish(self) -> None:
        """Flush: process everything queued (deterministic) or join the worker (realtime)."""
        self._queue.finish()

    # ------------------------------------------------------------------ one local BA
    def process(self, kf_id: int) -> BAResult | None:
        """Windowed BA around keyframe ``kf_id``, write-back and culling."""
        t0 = time.perf_counter()
        with self.lock:
            if self.config.fuse and (self.sensor != "mono" or self.config.fuse_mono):
                self._fuse_neighbours(kf_id)
            built = self._build_local(kf_id)
            epoch = self.map.loop_epoch
            n_links = 0
            if built is not None and self.dense_links:
                from vslam.backend.dense_links import add_dense_links

                linked, n_links = add_dense_links(built[0], self.dense_links)
                built = (linked, built[1])
        if built is None:
            return None
        problem, ctx = built
        try:
            result = local_bundle_adjustment(problem, self.config.local)
        except Exception as exc:  # GeometryError or a singular system: keep the map as it is
            self.counts["failed"] += 1
            LOG.warning("local BA on keyframe %d failed: %s", kf_id, exc)
            return None
        if n_links:
            from vslam.backend.dense_links import strip_dense_links

            problem, result = strip_dense_links(problem, result, n_links)
        with self.lock:
            if self.map.loop_epoch != epoch:  # realtime: a loop correction moved the map meanwhile
                self.counts["stale_dropped"] = self.counts.get("stale_dropped", 0) + 1
                LOG.info("local BA on keyframe %d dropped: a loop correction moved the map meanwhile", kf_id)
                return None
            self._apply(problem, result, ctx)
            self._cull_points(kf_id)
            if self.config.cull_keyframes:
                self._cull_keyframes(kf_id)
            self._update_bad_keyframes()
        self._times.append(time.perf_counter() - t0)
        self._solve_times.append(result.time_s)
        self.counts["local_ba_calls"] += 1
        LOG.debug("local BA kf %d: %d kfs (%d fixed), %d pts, rms %.2f -> %.2f px, %.0f ms", kf_id,
                  problem.num_keyframes, len(ctx.fixed), problem.num_points, result.initial_rms_px,
                  result.final_rms_px, 1e3 * result.time_s)
        return result

    def _window(self, kf: KeyFrame) -> tuple[list[int], list[int]]:
        """``(optimized keyframe ids, constant keyframe ids)`` of the local BA around ``kf``."""
        cfg = self.config
        seg = _segment_keyframes(self.map, kf.segment)
        good = {k.id for k in seg}
        first = min(good)
        recent = sorted(good)[-cfg.local.window_size:]
        cov = [k for k in self.map.covisible(kf.id) if k in good][: cfg.covisible_keyframes]
        window = sorted(set(recent) | set(cov) | {kf.id})
        # constant: covisible keyframes outside the window (they observe window points), strongest first
        weight: dict[int, int] = {}
        for k in window:
            for o, w in self.map.covisibility.get(k, {}).items():
                if o in good and o not in window:
                    weight[o] = weight.get(o, 0) + w
        fixed = sorted(weight, key=lambda o: (-weight[o], o))[: cfg.max_fixed_keyframes]
        if first in window and len(window) > 1:  # the segment's origin never moves
            window.remove(first)
            fixed.append(first)
        need = 2 if self.sensor == "mono" else 1
        while len(fixed) < need and len(window) > 1:
            fixed.append(window.pop(0))
        return window, sorted(fixed)

    def _build_local(self, kf_id: int) -> tuple[BAProblem, _Context] | None:
        kf = self.map.keyframes.get(kf_id)
        if kf is None or kf.bad:
            return None
        window, fixed = self._window(kf)
        if not window:
            return None
        pts = self.map.local_point_ids(window)
        return self._problem(window, fixed, pts, kf_id)

    def _problem(self, var_ids: list[int], fixed_ids: list[int], pts: np.ndarray,
                 new_kf: int) -> tuple[BAProblem, _Context] | None:
        """Gather the observations of points ``pts`` in the given keyframes (vectorized per keyframe)."""
        store = self.map.points
        n_rows = len(store)
        if len(pts) == 0:
            return None
        member = np.zeros(n_rows + 1, bool)
        member[pts] = True
        kf_ids = list(var_ids) + list(fixed_ids)
        cols: dict[str, list[np.ndarray]] = {k: [] for k in ("kf", "pt", "idx", "uv", "sig", "ur", "d")}
        for kid in kf_ids:
            k = self.map.keyframes[kid]
            pid = k.point_ids
            sel = np.flatnonzero(member[np.where(pid >= 0, pid, n_rows)])
            if len(sel) == 0:
                continue
            _, first = np.unique(pid[sel], return_index=True)  # one observation per point and keyframe
            sel = sel[np.sort(first)]
            cols["kf"].append(np.full(len(sel), kid, np.int64))
            cols["pt"].append(pid[sel])
            cols["idx"].append(sel)
            cols["uv"].append(k.uv_undist[sel])
            cols["sig"].append(np.power(self.scale_factor, k.octave[sel].astype(float)))
            nan = np.full(len(sel), np.nan)
            if self.sensor == "stereo" and k.u_right is not None:
                # keep the measured disparity, expressed at the undistorted left column
                disp = k.uv[sel, 0] - k.u_right[sel]
                ok = np.isfinite(disp) & (disp > 0) & np.isfinite(k.depth[sel])
                if self.config.stereo_far_baselines > 0:  # far points: the disparity is too weak, mono only
                    ok &= k.depth[sel] < self.config.stereo_far_baselines * float(self.camera.baseline)
                cols["ur"].append(np.where(ok, k.uv_undist[sel, 0] - disp, np.nan))
                cols["d"].append(nan)
            elif self.sensor == "rgbd":
                d = k.depth[sel]
                cols["ur"].append(nan)
                cols["d"].append(np.where(np.isfinite(d) & (d > 0), d, np.nan))
            else:
                cols["ur"].append(nan)
                cols["d"].append(nan)
        if not cols["kf"]:
            return None
        c = {k: np.concatenate(v) for k, v in cols.items()}
        # a point needs two observations, or one with depth / disparity, to be determined
        pt_ids, inv = np.unique(c["pt"], return_inverse=True)
        n_obs = np.bincount(inv, minlength=len(pt_ids))
        has3 = np.bincount(inv, weights=(np.isfinite(c["ur"]) | np.isfinite(c["d"])).astype(float),
                           minlength=len(pt_ids)) > 0
        ok_pt = (n_obs >= 2) | has3
        if self.sensor != "mono" and self.config.depthless_min_parallax_deg > 0:
            # stereo / RGB-D: a point without any depth or disparity here (far stereo points enter
            # as monocular) whose rays barely diverge has an unobservable depth
            ok_pt &= has3 | (max_parallax_deg(self._centres(kf_ids, c["kf"]), store.position[c["pt"]], inv, len(pt_ids))
                             >= self.config.depthless_min_parallax_deg)
        left_out = None
        if self.sensor == "mono" and self.config.mono_min_observations > 2:
            # two-view points: the least constrained depth, which BA pushes outwards (~1 % per
            # window on KITTI 07) and the next keyframe's PnP turns into scale drift; they stay in
            # the map as triangulated (and join BA once a third keyframe sees them). Not in the
            # first windows, where every point is a two-view one.
            multi = n_obs >= self.config.mono_min_observations
            if multi.sum() >= self.config.mono_min_multiview_points:
                if self.config.mono_left_out != "keep":
                    lo = (ok_pt & ~multi)[inv]
                    left_out = (c["pt"][lo], c["kf"][lo], c["uv"][lo])
                ok_pt &= multi
        keep = ok_pt[inv]
        c = {k: v[keep] for k, v in c.items()}
        pt_ids = pt_ids[ok_pt]
        used_kf = [k for k in kf_ids if np.any(c["kf"] == k)]
        var_used = [k for k in var_ids if k in used_kf]
        if not var_used or len(pt_ids) == 0:
            return None
        fixed_used = [k for k in fixed_ids if k in used_kf]
        problem = BAProblem(
            camera=self.camera, kf_ids=np.array(used_kf, np.int64),
            T_world_cam=np.stack([self.map.keyframes[k].T_world_cam for k in used_kf]),
            pt_ids=pt_ids, X_world=store.position[pt_ids], obs_kf=c["kf"], obs_pt=c["pt"], obs_uv=c["uv"],
            obs_sigma=c["sig"], obs_u_right=c["ur"], obs_depth=c["d"],
            fixed_kf_ids=np.array(fixed_used, np.int64),
        )
        return problem, _Context(obs_idx=c["idx"], fixed=np.array(fixed_used, np.int64), n_rows=n_rows,
                                 new_kf=new_kf, left_out=left_out)

    def _centres(self, kf_ids: list[int], obs_kf: np.ndarray) -> np.ndarray:
        """Camera centre (world) of the keyframe of each observation ``obs_kf (M,)``."""
        ids = np.asarray(kf_ids, np.int64)
        order = np.argsort(ids)
        centres = np.stack([self.map.keyframes[k].T_world_cam[:3, 3] for k in ids])
        return centres[order[np.searchsorted(ids[order], obs_kf)]]

    # ------------------------------------------------------------------ fusion (SearchInNeighbors)
    def _fuse_neighbours(self, kf_id: int) -> None:
        """ORB-SLAM2 ``SearchInNeighbors`` (Mur-Artal & Tardos 2017, Sec. VI-B): project the window
        keyframes' points into the new keyframe and the new keyframe's points into the window
        keyframes; a descriptor match whose reprojection (and disparity) error passes the chi-square
        test adds the observation, or fuses two points that are one (the one with fewer
        observations is replaced everywhere). This links keyframes through shared points, which is
        what gives local BA its constraints."""
        kf = self.map.keyframes.get(kf_id)
        if kf is None or kf.bad or kf.descriptors is None or self.map.points.descriptor is None:
            return
        window, _ = self._window(kf)
        neighbours = [self.map.keyframes[k] for k in window if k != kf_id]
        if not neighbours:
            return
        store = self.map.points
        remap = new_remap(len(store))
        # neighbours' points -> new keyframe
        pts = self.map.local_point_ids([k.id for k in neighbours])
        n_fused = self._fuse_into(kf, pts, remap)
        # new keyframe's points -> each neighbour
        own = kf.observed_ids()
        own = unique_ids(len(store), own[store.alive[own]])
        for nb in neighbours:
            n_fused += self._fuse_into(nb, own, remap)
        if n_fused:
            apply_remap(self.map.keyframes.values(), remap)
        self.map.update_covisibility(kf_id)
        self.counts["fused_points"] = self.counts.get("fused_points", 0) + n_fused

    def _fuse_into(self, kf: KeyFrame, pts: np.ndarray, remap: np.ndarray) -> int:
        """Match points ``pts`` into keyframe ``kf``; returns the number of points fused away."""
        from vslam.map.matching import guided_match, project_local_points

        store = self.map.points
        pts = pts[store.alive[pts]]
        if len(pts) == 0 or len(kf.uv_undist) == 0:
            return 0
        pts = unique_ids(len(store), pts, exclude=kf.point_ids[kf.point_ids >= 0])
        vis, uv, z = project_local_points(store, pts, kf.T_cam_world, self.camera)
        if len(vis) == 0:
            return 0
        binary = kf.descriptors.dtype == np.uint8
        m, k, _ = guided_match(uv, store.descriptor[vis], kf.uv_undist, kf.descriptors, self.config.fuse_radius_px,
                               binary, self.config.fuse_max_descriptor_distance if binary else None,
                               ratio=self.config.fuse_ratio,
                               kp_tree=kf.keypoint_tree())
        if len(m) == 0:
            return 0
        p, kp, zp = vis[m], k, z[m]
        sigma2 = np.power(self.scale_factor, 2.0 * kf.octave[kp].astype(float))
        chi2 = np.sum((uv[m] - kf.uv_undist[kp]) ** 2, axis=1) / sigma2
        thr = np.full(len(p), self.config.local.chi2_mono)
        if self.sensor != "mono" and kf.u_right is not None:
            if self.sensor == "stereo":
                bf, u0 = self.camera.fx * float(self.camera.baseline), kf.uv[kp, 0]
            else:
                bf, u0 = self.camera.fx * self.config.local.rgbd_virtual_baseline, kf.uv_undist[kp, 0]
            disp = u0 - kf.u_right[kp]
            has = np.isfinite(disp)
            chi2 = chi2 + np.where(has, (np.where(has, disp, 0.0) - bf / zp) ** 2, 0.0) / sigma2
            thr = np.where(has, self.config.local.chi2_stereo, thr)
        ok = chi2 <= thr
        p, kp = p[ok], kp[ok]
        cur = kf.point_ids[kp]
        # keypoint free (or its point is dead): a new observation
        free = (cur < 0) | ~store.alive[np.where(cur >= 0, cur, 0)]
        kf.point_ids[kp[free]] = p[free]
        np.add.at(store.n_obs, p[free], 1)
        # keypoint with another live point: the two are the same point; keep the better observed one
        dup = ~free & (cur != p)
        a, b = p[dup], cur[dup]
        a, b = remap[a], remap[b]  # already fused earlier in this pass
        keep_a = store.n_obs[a] >= store.n_obs[b]
        return self.map.merge_points(np.where(keep_a, b, a), np.where(keep_a, a, b), remap)

    # ------------------------------------------------------------------ write-back and culling
    def _apply(self, problem: BAProblem, result: BAResult, ctx: _Context) -> None:
        """Poses, points and outlier observations back into the map (under the lock)."""
        store = self.map.points
        if len(store) < ctx.n_rows:
            LOG.info("map compacted during local BA: result dropped")
            return
        fixed = np.isin(result.kf_ids, ctx.fixed)
        moved = None
        corrections: dict[int, np.ndarray] = {}
        for kid, T, f in zip(result.kf_ids.tolist(), result.T_world_cam, fixed):
            kf = self.map.keyframes.get(kid)
            if kf is not None and not f and np.all(np.isfinite(T)):
                if kid == self._newest_kf():
                    moved = (kid, kf.T_world_cam.copy(), T.copy())
                if ctx.left_out is not None:
                    corrections[kid] = T @ np.linalg.inv(kf.T_world_cam)
                kf.T_world_cam = T.copy()
        if ctx.left_out is not None and len(ctx.left_out[0]) and corrections:
            if self.config.mono_left_out == "retriangulate":
                self._retriangulate_left_out(*ctx.left_out, corrections)
            else:
                self._transport_left_out(ctx.left_out[0], corrections)
        if moved is not None:
            for cb in self.correction_listeners:
                cb(*moved)
        alive = store.alive[result.pt_ids]
        good_X = alive & np.all(np.isfinite(result.X_world), axis=1)
        store.position[result.pt_ids[good_X]] = result.X_world[good_X]
        self._update_normals(problem, result, good_X)
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

    def _transport_left_out(self, pt: np.ndarray, corrections: dict[int, np.ndarray]) -> None:
        """``mono_left_out=transport``: a point left out of a monocular BA keeps its coordinates in
        its reference (first) keyframe, i.e. moves with that keyframe's correction
        ``X <- T_after T_before^-1 X`` (as loop correction moves points, ORB-SLAM2 CorrectLoop), so
        tracking does not meet stale points next to corrected poses."""
        store = self.map.points
        ids = np.unique(pt)
        ids = ids[store.alive[ids]]
        ref = store.first_kf[ids]
        for kid, D in corrections.items():
            m = ids[ref == kid]
            if len(m):
                store.position[m] = store.position[m] @ D[:3, :3].T + D[:3, 3]

    def _retriangulate_left_out(self, pt: np.ndarray, kf: np.ndarray, uv: np.ndarray,
                                corrections: dict[int, np.ndarray]) -> None:
        """``mono_left_out=retriangulate``: points left out of a monocular BA (two-view points) are triangulated
        again (linear DLT, HZ 12.2) from their two observations with the corrected keyframe poses, so
        tracking does not meet stale points next to corrected poses (see the config for the measured
        trade-off). A point whose new triangulation is not in front of both keyframes keeps its
        position."""
        from vslam.geometry.triangulation import triangulate

        store = self.map.points
        order = np.lexsort((kf, pt))
        pt, kf, uv = pt[order], kf[order], uv[order]
        starts = np.flatnonzero(np.r_[True, pt[1:] != pt[:-1]])
        counts = np.diff(np.r_[starts, len(pt)])
        s = starts[counts >= 2]
        ids, ka, kb, ua, ub = pt[s], kf[s], kf[s + 1], uv[s], uv[s + 1]
        moved = np.isin(ka, list(corrections)) | np.isin(kb, list(corrections))
        sel = moved & store.alive[ids]
        pairs = np.unique(np.stack([ka[sel], kb[sel]], axis=1), axis=0)
        for a, b in pairs.tolist():
            m = sel & (ka == a) & (kb == b)
            Ta, Tb = self.map.keyframes[a].T_cam_world, self.map.keyframes[b].T_cam_world
            X = triangulate(Ta, Tb, self.camera.K, ua[m], ub[m])
            za = X @ Ta[2, :3] + Ta[2, 3]
            zb = X @ Tb[2, :3] + Tb[2, 3]
            ok = np.all(np.isfinite(X), axis=1) & (za > 0) & (zb > 0)
            store.position[ids[m][ok]] = X[ok]

    def _update_normals(self, problem: BAProblem, result: BAResult, good: np.ndarray) -> None:
        """ORB-SLAM's UpdateNormalAndDepth after the points moved: the viewing direction is the mean
        unit ray from the observing keyframes, the distance range is rescaled to the new distance
        from one observing keyframe (the tracker's visibility test uses both)."""
        store = self.map.points
        pt_row = problem.pt_index(problem.obs_pt)
        kf_row = problem.kf_index(problem.obs_kf)
        T = result.T_world_cam
        X = result.X_world[pt_row]
        ray = X - T[kf_row, :3, 3]
        dist = np.linalg.norm(ray, axis=1)
        unit = ray / np.maximum(dist, 1e-12)[:, None]
        acc = np.zeros((problem.num_points, 3))
        np.add.at(acc, pt_row, unit)
        norm = np.linalg.norm(acc, axis=1)
        ok = good & (norm > 1e-9)
        ids = problem.pt_ids[ok]
        store.normal[ids] = acc[ok] / norm[ok, None]
        # distance range from the last observation of each point (scale-invariance, ORB-SLAM sec. III-C)
        last = np.full(problem.num_points, -1, np.int64)
        last[pt_row] = np.arange(len(pt_row))
        has = ok & (last >= 0)
        o = last[has]
        ids = problem.pt_ids[has]
        old_max, old_min = store.max_distance[ids], store.min_distance[ids]
        ratio = np.where((old_min > 0) & np.isfinite(old_max), old_max / np.maximum(old_min, 1e-12), 1.0)
        new_max = dist[o] * problem.obs_sigma[o]
        store.max_distance[ids] = new_max
        store.min_distance[ids] = new_max / np.maximum(ratio, 1.0)

    def _newest_kf(self) -> int:
        return max(self.map.keyframes) if self.map.keyframes else -1

    def _cull_points(self, kf_id: int) -> None:
        """Points without observations die; so do points born two keyframes ago (in this segment)
        that fewer than ``cull_min_observations`` keyframes observe (ORB-SLAM2 MapPointCulling, with
        the keyframe count as the age; each point is judged once)."""
        store = self.map.points
        n = len(store)
        if n == 0:
            return
        alive = store.alive[:n]
        dead = alive & (store.n_obs[:n] <= 0)
        k_min = self.config.cull_min_observations
        kf = self.map.keyframes.get(kf_id)
        if k_min > 1 and kf is not None:
            seg_ids = sorted(k.id for k in _segment_keyframes(self.map, kf.segment))
            age = self.config.cull_age_keyframes
            if len(seg_ids) >= age:
                upto = seg_ids[-age]  # points born two keyframes ago had their chance to be re-observed
                first = store.first_kf[:n]
                lo = self._culled_upto.get(kf.segment, -1)
                recent = alive & (first > lo) & (first <= upto)
                dead |= recent & (store.n_obs[:n] < k_min)
                self._culled_upto[kf.segment] = upto
        if dead.any():
            store.alive[:n][dead] = False
            self.counts["culled_points"] += int(dead.sum())

    def _cull_keyframes(self, kf_id: int) -> None:
        """ORB-SLAM KeyFrameCulling over the covisible keyframes of ``kf_id``: a keyframe whose
        points are >= ``redundant_ratio`` observed by >= ``redundant_min_observers`` other keyframes is flagged bad."""
        store = self.map.points
        kf = self.map.keyframes.get(kf_id)
        if kf is None:
            return
        seg = _segment_keyframes(self.map, kf.segment)
        n_recent = self.config.cull_keep_recent_keyframes
        if len(seg) < n_recent + 1:
            return
        first = min(k.id for k in seg)
        recent = {k.id for k in sorted(seg, key=lambda k: k.id)[-n_recent:]}
        for cid in self.map.covisible(kf_id):
            c = self.map.keyframes.get(cid)
            if c is None or c.bad or c.id == first or c.id in recent or c.segment != kf.segment:
                continue
            ids = unique_ids(len(store), c.observed_ids())
            ids = ids[store.alive[ids]]
            if len(ids) == 0:
                continue
            seen = np.zeros(len(ids), np.int64)
            in_o = np.zeros(len(store), dtype=bool)  # per other keyframe: which points it observes
            for oid in self.map.covisibility.get(cid, {}):
                o = self.map.keyframes.get(oid)
                if o is None or o.bad or o.id == cid:
                    continue
                obs = o.observed_ids()
                in_o[obs] = True
                seen += in_o[ids]
                in_o[obs] = False
            if np.mean(seen >= self.config.redundant_min_observers) >= self.config.redundant_ratio:
                self._set_bad(c)

    def _set_bad(self, kf: KeyFrame) -> None:
        links = self.map.covisibility.get(kf.id, {})
        parents = [o for o in sorted(links, key=lambda o: (-links[o], o))
                   if o in self.map.keyframes and not self.map.keyframes[o].bad]
        if not parents:
            return
        parent = self.map.keyframes[parents[0]]
        kf.extra["parent"] = parent.id
        kf.extra["T_parent_kf"] = np.linalg.inv(parent.T_world_cam) @ kf.T_world_cam
        kf.bad = True
        for o in list(links):
            self.map.covisibility.get(o, {}).pop(kf.id, None)
        self.map.covisibility[kf.id] = {}
        ids = kf.observed_ids()
        np.subtract.at(self.map.points.n_obs, ids, 1)
        self.counts["culled_keyframes"] += 1

    def _update_bad_keyframes(self) -> None:
        """Culled keyframes follow their parent rigidly (so frames referencing them stay placed)."""
        for kf in self.map.keyframes.values():
            if not kf.bad or "parent" not in kf.extra:
                continue
            chain, p = [], kf
            while p.bad and "parent" in p.extra and len(chain) < 100:
                chain.append(p.extra["T_parent_kf"])
                p = self.map.keyframes[p.extra["parent"]]
            T = p.T_world_cam
            for T_rel in reversed(chain):
                T = T @ T_rel
            kf.T_world_cam = T

    # ------------------------------------------------------------------ global BA
    def global_ba(self) -> BAResult | None:
        """Full BA over every good keyframe and live point; each segment's first keyframe (two for
        monocular, also fixing the scale) is constant.

        The problem is snapshot under the map lock and solved without it (in realtime mode tracking
        goes on meanwhile); the write-back takes the lock again, and keyframes created during the
        solve (and the points they created) move with the newest optimized keyframe of their segment
        (ORB-SLAM2's RunGlobalBundleAdjustment propagation through the spanning tree). A result made
        stale by a loop correction during the solve is dropped."""
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

                problem, n_links = add_dense_links(problem, self.dense_links)
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
        with self.lock:
            if self.map.loop_epoch != epoch:
                LOG.info("global BA dropped: a loop correction moved the map during the solve")
                return None
            before = {kid: self.map.keyframes[kid].T_world_cam.copy() for kid in result.kf_ids.tolist()
                      if kid in self.map.keyframes}
            self._apply(problem, result, ctx)
            self._propagate_to_new_keyframes(before, known)
            self._update_bad_keyframes()
            self.map.loop_epoch += 1  # local BAs built before this write-back are stale now
        self.counts["global_ba_calls"] = self.counts.get("global_ba_calls", 0) + 1
        self.global_ba_result = {
            "keyframes": problem.num_keyframes, "points": problem.num_points,
            "observations": problem.num_observations, "initial_rms_px": round(result.initial_rms_px, 4),
            "final_rms_px": round(result.final_rms_px, 4), "iterations": result.iterations,
            "ms": round(1e3 * (time.perf_counter() - t0), 1),
        }
        LOG.info("global BA: %s", self.global_ba_result)
        return result

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
        out["local_ba_skipped"] += self._queue.skipped  # realtime: keyframes that piled up
        out["failed"] += self._queue.failed
        out["mode"] = "realtime" if self.config.mode == "realtime" else "deterministic"
        out["local_ba_ms_mean"] = round(1e3 * float(t.mean()), 2) if len(t) else 0.0
        out["local_ba_ms_median"] = round(1e3 * float(np.median(t)), 2) if len(t) else 0.0
        out["local_ba_ms_total"] = round(1e3 * float(t.sum()), 1)
        out["local_ba_solver_ms_mean"] = round(1e3 * float(np.mean(self._solve_times)), 2) if self._solve_times else 0.0
        if self.global_ba_result is not None:
            out["global_ba"] = self.global_ba_result  # the last one (final_ba, or a loop closure's)
        return out

