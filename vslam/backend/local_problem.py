"""The local BA problem around a new keyframe: the window of optimized keyframes, the constant
keyframes that fix the gauge, and the observations of their points (see
:mod:`vslam.backend.local_mapping`, steps 1-2)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vslam.backend.config import BackendConfig
from vslam.backend.local_problem_kernels import gather_keyframe, scatter_min, unit_rays
from vslam.backend.problem import BAProblem
from vslam.geometry.camera import PinholeCamera
from vslam.map.keyframe import KeyFrame
from vslam.map.map import Map


@dataclass
class ProblemContext:
    """What :meth:`LocalMapper._apply` needs besides the problem: keypoint index of each observation,
    which keyframes were constant, and the store size (to detect a compaction in between)."""

    obs_idx: np.ndarray
    fixed: np.ndarray
    n_rows: int
    new_kf: int
    left_out: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # monocular points kept out: (pt, kf, uv) per observation


def row_norms(a: np.ndarray) -> np.ndarray:
    """Euclidean norm of each row of ``a (M, 3)``: ``np.linalg.norm(a, axis=1)`` to the last bit (its
    squares summed in the same order, x, y, z), without the generic reduction (~5x faster)."""
    return np.sqrt(a[:, 0] * a[:, 0] + a[:, 1] * a[:, 1] + a[:, 2] * a[:, 2])


def max_parallax_deg(centres: np.ndarray, X_world: np.ndarray, point: np.ndarray, n_points: int) -> np.ndarray:
    """Per point, the largest angle (degrees) between its first observation's viewing ray and the
    others (a lower bound of the largest pairwise parallax, at least half of it; 0 for one observation).

    ``centres (M, 3)``: the observing camera centre per observation, ``X_world (M, 3)``: the point per
    observation, ``point (M,)``: point row of each observation in ``0 .. n_points - 1``. Parallax as
    in ORB-SLAM2's triangulation test (Mur-Artal & Tardos 2017: ``cos`` of the ray angle > 0.9998 is
    too little), vectorized over observations.
    """
    ray = X_world - centres
    ray /= np.maximum(row_norms(ray), 1e-12)[:, None]
    return parallax_of_rays(ray, point, n_points)


def parallax_of_rays(ray: np.ndarray, point: np.ndarray, n_points: int) -> np.ndarray:
    """:func:`max_parallax_deg` from the unit rays ``ray (M, 3)`` of the observations."""
    first = np.full(n_points, -1, np.int64)
    first[point[::-1]] = np.arange(len(point))[::-1]  # the last write wins: the first observation
    cos = np.einsum("ij,ij->i", ray, ray[first[point]])
    min_cos = np.ones(n_points)
    scatter_min(min_cos, np.asarray(point, np.int64), cos)  # np.minimum.at, compiled
    return np.degrees(np.arccos(np.clip(min_cos, -1.0, 1.0)))


def unique_rows(rows: np.ndarray, n_rows: int) -> tuple[np.ndarray, np.ndarray]:
    """``np.unique(rows, return_inverse=True)`` for ids in ``0 .. n_rows - 1``, by a flag and a
    position table over the id range instead of a sort."""
    flag = np.zeros(n_rows, dtype=bool)
    flag[rows] = True
    ids = np.flatnonzero(flag)
    pos = np.empty(n_rows, np.int64)
    pos[ids] = np.arange(len(ids))
    return ids, pos[rows]


_NO_DEPTH = np.empty(0)  # the depth arguments of gather_keyframe without depth (mono, stereo)


def segment_keyframes(map_: Map, segment: int) -> list[KeyFrame]:
    return [k for k in map_.keyframes.values() if k.segment == segment and not k.bad]




class LocalProblemBuilder:
    """Builds the BA problems of :class:`vslam.backend.local_mapping.LocalMapper`."""

    def __init__(self, map_: Map, camera: PinholeCamera, sensor: str, config: BackendConfig,
                 scale_factor: float) -> None:
        self.map = map_
        self.camera = camera
        self.sensor = sensor
        self.config = config
        self.scale_factor = scale_factor
        # scratch of member_keypoints kept between builds: entries equal to a tag mark the points a
        # keyframe took; every keyframe of every build gets a new tag, so it never needs a refill
        self._stamp = np.full(0, -1, np.int64)
        self._next_tag = 0

    def window(self, kf: KeyFrame) -> tuple[list[int], list[int]]:
        """``(optimized keyframe ids, constant keyframe ids)`` of the local BA around ``kf``."""
        cfg = self.config
        seg = segment_keyframes(self.map, kf.segment)
        good = {k.id for k in seg}
        first = min(good)
        size = cfg.mono.window_size if (self.sensor == "mono" and cfg.mono.window_size) else cfg.local.window_size
        recent = sorted(good)[-size:]
        cov = [k for k in self.map.covisible(kf.id) if k in good][: cfg.covisible_keyframes]
        window = sorted(set(recent) | set(cov) | {kf.id})
        # constant: covisible keyframes outside the window (they observe window points), strongest first
        weight: dict[int, int] = {}
        outside = good.difference(window)
        for k in window:
            links = self.map.covisibility.get(k, {})
            for o in links.keys() & outside:  # sums of ints, sorted below by a total order: any visit order
                weight[o] = weight.get(o, 0) + links[o]
        fixed = sorted(weight, key=lambda o: (-weight[o], o))[: cfg.max_fixed_keyframes]
        if first in window and len(window) > 1:  # the segment's origin never moves
            window.remove(first)
            fixed.append(first)
        need = 2 if self.sensor == "mono" else 1
        while len(fixed) < need and len(window) > 1:
            fixed.append(window.pop(0))
        return window, sorted(fixed)

    def build_local(self, kf_id: int) -> tuple[BAProblem, ProblemContext] | None:
        kf = self.map.keyframes.get(kf_id)
        if kf is None or kf.bad:
            return None
        window, fixed = self.window(kf)
        if not window:
            return None
        pts = self.map.local_point_ids(window)
        return self.build(window, fixed, pts, kf_id)

    def build(self, var_ids: list[int], fixed_ids: list[int], pts: np.ndarray,
              new_kf: int) -> tuple[BAProblem, ProblemContext] | None:
        """Gather the observations of points ``pts`` in the given keyframes (vectorized per keyframe)."""
        store = self.map.points
        n_rows = len(store)
        if len(pts) == 0:
            return None
        member = np.zeros(n_rows + 1, bool)
        member[pts] = True
        kf_ids = list(var_ids) + list(fixed_ids)
        cols = self._gather(kf_ids, member, n_rows)
        if not cols["kf"]:
            return None
        c = {k: v[0] if len(v) == 1 else np.concatenate(v) for k, v in cols.items()}  # (one array: no copy)
        # a point needs two observations, or one with depth / disparity, to be determined
        pt_ids, inv = unique_rows(c["pt"], n_rows)
        n_obs = np.bincount(inv, minlength=len(pt_ids))
        has3 = np.bincount(inv, weights=(np.isfinite(c["ur"]) | np.isfinite(c["d"])).astype(float),
                           minlength=len(pt_ids)) > 0
        ok_pt = (n_obs >= 2) | has3
        if self.sensor != "mono" and self.config.depthless_min_parallax_deg > 0:
            # stereo / RGB-D: a point without any depth or disparity here (far stereo points enter
            # as monocular) whose rays barely diverge has an unobservable depth
            ray = np.empty((len(inv), 3))  # the unit rays of max_parallax_deg, gathered in one compiled pass
            unit_rays(store.position, c["pt"], self._centre_lut(kf_ids), c["kf"], ray)
            ok_pt &= has3 | (parallax_of_rays(ray, inv, len(pt_ids)) >= self.config.depthless_min_parallax_deg)
        left_out = None
        if self.sensor == "mono" and self.config.mono.min_observations > 2:
            # two-view points: the least constrained depth, which BA pushes outwards (~1 % per
            # window on KITTI 07) and the next keyframe's PnP turns into scale drift; they stay in
            # the map as triangulated (and join BA once a third keyframe sees them). Not in the
            # first windows, where every point is a two-view one.
            multi = n_obs >= self.config.mono.min_observations
            if multi.sum() >= self.config.mono.min_multiview_points:
                if self.config.mono.left_out != "keep":
                    lo = (ok_pt & ~multi)[inv]
                    left_out = (c["pt"][lo], c["kf"][lo], c["uv"][lo])
                ok_pt &= multi
        if ok_pt.all():  # (the arrays of c are this build's own: no copy needed)
            pt_rows = inv  # each observation's row in pt_ids
        else:
            keep = ok_pt[inv]
            c = {k: v[keep] for k, v in c.items()}
            pt_ids = pt_ids[ok_pt]
            pt_rows = (np.cumsum(ok_pt) - 1)[inv[keep]]  # each kept observation's row in pt_ids
        seen = np.zeros(max(kf_ids) + 1, bool)
        seen[c["kf"]] = True
        used_kf = [k for k in kf_ids if seen[k]]
        var_used = [k for k in var_ids if k in used_kf]
        if not var_used or len(pt_ids) == 0:
            return None
        fixed_used = [k for k in fixed_ids if k in used_kf]
        kf_lut = np.zeros(max(kf_ids) + 1, np.int64)
        kf_lut[used_kf] = np.arange(len(used_kf))
        problem = BAProblem(
            camera=self.camera, kf_ids=np.array(used_kf, np.int64),
            T_world_cam=np.stack([self.map.keyframes[k].T_world_cam for k in used_kf]),
            pt_ids=pt_ids, X_world=store.position[pt_ids], obs_kf=c["kf"], obs_pt=c["pt"], obs_uv=c["uv"],
            obs_sigma=c["sig"], obs_u_right=c["ur"], obs_depth=c["d"],
            fixed_kf_ids=np.array(fixed_used, np.int64), obs_rows=(kf_lut[c["kf"]], pt_rows),
        )
        return problem, ProblemContext(obs_idx=c["idx"], fixed=np.array(fixed_used, np.int64), n_rows=n_rows,
                                 new_kf=new_kf, left_out=left_out)

    def _gather(self, kf_ids: list[int], member: np.ndarray, n_rows: int) -> dict[str, list[np.ndarray]]:
        """Per keyframe, its observations of the points flagged in ``member``: keyframe, point,
        keypoint index, undistorted pixel, sigma, virtual right coordinate (stereo), depth (RGB-D).

        Per keyframe only the gathers; the element-wise expressions (sigma, the depth and disparity
        tests) run once on the concatenation (the same values, element by element)."""
        cols: dict[str, list[np.ndarray]] = {k: [] for k in ("kf", "pt", "idx", "uv", "sig", "ur", "d")}
        if len(self._stamp) < n_rows + 1:  # the store grew: a larger scratch (tags only increase)
            self._stamp = np.full(max(n_rows + 1, 2 * len(self._stamp)), -1, np.int64)
        stamp, tag0 = self._stamp, self._next_tag
        self._next_tag += len(kf_ids)
        stereo, rgbd = self.sensor == "stereo", self.sensor == "rgbd"
        kfs = [self.map.keyframes[kid] for kid in kf_ids]
        if not kfs:
            return cols
        total = sum(len(k.point_ids) for k in kfs)
        # one compiled pass per keyframe (selection and gathers) into buffers for all of them
        oct_dtype = np.result_type(*[k.octave.dtype for k in kfs])
        out_pt, out_idx = np.empty(total, np.int64), np.empty(total, np.int64)
        out_uv, out_oct = np.empty((total, 2)), np.empty(total, oct_dtype)
        out_d = np.empty(total) if rgbd else _NO_DEPTH
        u_l, u_r, depth, n_sel, kf_used = [], [], [], [], []
        n = 0
        for tag, (kid, k) in enumerate(zip(kf_ids, kfs)):
            # one observation per point and keyframe, the first
            n_next = gather_keyframe(np.asarray(k.point_ids, np.int64), member, stamp, tag0 + tag,
                                     np.asarray(k.uv_undist, float), np.asarray(k.octave, oct_dtype),
                                     np.asarray(k.depth, float) if rgbd else _NO_DEPTH, rgbd, out_pt, out_idx,
                                     out_uv, out_oct, out_d, n)
            if n_next == n:
                continue
            n_sel.append(n_next - n)
            kf_used.append(kid)
            if stereo:
                # keep the measured disparity, expressed at the undistorted left column (NaN: mono rows)
                sel = out_idx[n:n_next]
                u_l.append(k.uv[sel, 0])
                u_r.append(k.u_right[sel] if k.u_right is not None else np.full(len(sel), np.nan))
                depth.append(k.depth[sel] if k.u_right is not None else np.full(len(sel), np.nan))
            n = n_next
        if not n_sel:
            return cols
        cols["pt"], cols["idx"], cols["uv"] = [out_pt[:n]], [out_idx[:n]], [out_uv[:n]]
        octave = [out_oct[:n]]
        if rgbd:
            depth = [out_d[:n]]
        cols["kf"] = [np.repeat(np.asarray(kf_used, np.int64), n_sel)]
        cols["sig"] = [np.power(self.scale_factor, np.concatenate(octave).astype(float))]
        nan = np.full(sum(n_sel), np.nan)
        ur, d = nan, nan
        if stereo:
            uv_x = np.concatenate(cols["uv"])[:, 0]
            dep = np.concatenate(depth)
            disp = np.concatenate(u_l) - np.concatenate(u_r)
            ok = np.isfinite(disp) & (disp > 0) & np.isfinite(dep)
            if self.config.stereo_far_baselines > 0:  # far points: the disparity is too weak, mono only
                ok &= dep < self.config.stereo_far_baselines * float(self.camera.baseline)
            ur = np.where(ok, uv_x - disp, np.nan)
        elif rgbd:
            dep = np.concatenate(depth)
            d = np.where(np.isfinite(dep) & (dep > 0), dep, np.nan)
        cols["ur"], cols["d"] = [ur], [d]
        return cols

    def _centre_lut(self, kf_ids: list[int]) -> np.ndarray:
        """Camera centres (world) by keyframe id: row ``k`` for each ``k`` of ``kf_ids`` (others unset)."""
        lut = np.empty((max(kf_ids) + 1, 3))
        lut[kf_ids] = np.stack([self.map.keyframes[k].T_world_cam[:3, 3] for k in kf_ids])
        return lut
