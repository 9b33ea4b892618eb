"""Geometric verification of a place-recognition match: descriptor matching, 3D-3D / Sim(3) RANSAC,
guided matching by projection and pose refinement.

Shared by loop closing (query keyframe vs the candidate keyframe's neighbourhood) and
relocalization (a lost frame vs a candidate keyframe). Follows ORB-SLAM (Mur-Artal et al., T-RO
2015): ``SearchByBoW`` -> ``Sim3Solver`` (Horn 1987 closed form inside RANSAC; here
:func:`vslam.geometry.align.align_points`, Umeyama 1991) -> ``SearchByProjection`` -> pose
optimization (:func:`vslam.geometry.pnp.refine_pose`, Huber-weighted Gauss-Newton with the
chi-square inlier test).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from vslam.errors import GeometryError
from vslam.features.match import match_descriptors
from vslam.geometry.align import align_points
from vslam.geometry.camera import PinholeCamera
from vslam.geometry.lie import inv_se3
from vslam.geometry.pnp import refine_pose
from vslam.map.mappoint import MapPointStore
from vslam.map.matching import guided_match, project_local_points

log = logging.getLogger(__name__)


@dataclass
class Features:
    """The keypoints of the frame (or keyframe) being localized.

    ``uv_undist (N, 2)``, ``descriptors (N, 32) uint8``, ``octave (N,)``, ``depth (N,)`` (NaN where
    unknown), ``u_right (N,)`` or None (stereo / RGB-D virtual right column), ``X_cam (N, 3)``
    optional 3D points in the camera frame (NaN where unknown; monocular: from the keyframe's own map
    points, so in its map's scale).
    """

    uv_undist: np.ndarray
    descriptors: np.ndarray
    octave: np.ndarray
    depth: np.ndarray
    u_right: np.ndarray | None = None
    X_cam: np.ndarray | None = None


def keyframe_features(slam_map, kf, camera: PinholeCamera, sensor: str) -> Features:
    """A keyframe's keypoints as :class:`Features`, with 3D points in its camera frame: from depth
    (RGB-D, stereo: ``X = d K^-1 [u v 1]^T``) or from its own map points (monocular: ``X = R_cw X_w +
    t_cw``, those in front of the camera)."""
    X = np.full((len(kf.uv_undist), 3), np.nan)
    if sensor == "mono":
        pid = kf.point_ids
        ok = pid >= 0
        ok[ok] = slam_map.points.alive[pid[ok]]
        T = kf.T_cam_world
        X[ok] = slam_map.points.position[pid[ok]] @ T[:3, :3].T + T[:3, 3]
        X[X[:, 2] <= 0] = np.nan
    else:
        d = kf.depth
        ok = np.isfinite(d) & (d > 0)
        X[ok] = camera.backproject(kf.uv_undist[ok], d[ok])
    return Features(kf.uv_undist, kf.descriptors, kf.octave, kf.depth, kf.u_right, X)


def keypoints_with_depth(slam_map, kf_ids: list[int], camera: PinholeCamera) -> dict[str, np.ndarray]:
    """World points, descriptors and source keyframe of the keypoints of ``kf_ids`` that have depth
    but no map point (RGB-D / stereo), as :func:`verify`'s keyword arguments ``extra_X``, ``extra_desc``
    and ``extra_src`` (empty when there are none): more RANSAC candidates. On texture-poor scenes most keypoints
    keep no map point (local mapping culls points few keyframes re-observe: on TUM fr3/cabinet
    keyframe 0 keeps none of its 216), so without these a revisit has nothing to match."""
    Xs, Ds, Ss = [], [], []
    for k in kf_ids:
        f = slam_map.keyframes[k]
        if f.descriptors is None or f.depth is None:
            continue
        pid = f.point_ids
        has_point = pid >= 0
        has_point[has_point] = slam_map.points.alive[pid[has_point]]
        ok = np.isfinite(f.depth) & (f.depth > 0) & ~has_point
        if not ok.any():
            continue
        Xc = camera.backproject(f.uv_undist[ok], f.depth[ok])
        Xs.append(Xc @ f.T_world_cam[:3, :3].T + f.T_world_cam[:3, 3])
        Ds.append(f.descriptors[ok])
        Ss.append(np.full(int(ok.sum()), k, np.int64))
    if not Xs:
        return {}
    return {"extra_X": np.concatenate(Xs), "extra_desc": np.concatenate(Ds), "extra_src": np.concatenate(Ss)}


@dataclass
class Verified:
    """An accepted geometric match.

    Attributes:
        T_world_cam: the frame's rigid pose in the candidate's world.
        scale: Sim(3) scale (monocular: the query map's scale relative to the candidate's; else 1).
        kp_idx, point_ids: the inlier correspondences (keypoint index -> candidate-side map point).
        n_inliers: ``len(kp_idx)``.
        n_ransac: inliers of the RANSAC stage.
    """

    T_world_cam: np.ndarray
    scale: float
    kp_idx: np.ndarray
    point_ids: np.ndarray
    n_inliers: int
    n_ransac: int

    @property
    def S_world_cam(self) -> np.ndarray:
        S = self.T_world_cam.copy()
        S[:3, :3] *= self.scale
        return S


def descriptor_candidates(feat: Features, store: MapPointStore, point_ids: np.ndarray, ratio: float,
                          max_distance: float) -> tuple[np.ndarray, np.ndarray]:
    """Brute-force ratio + mutual matching of the features to map points; ``(kp_idx, point_ids)``."""
    if store.descriptor is None or len(point_ids) < 2 or feat.descriptors is None or len(feat.descriptors) < 2:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    i1, i2, _ = match_descriptors(feat.descriptors, store.descriptor[point_ids], binary=True, ratio=ratio,
                                  mutual=True, max_distance=max_distance)
    return np.asarray(i1, np.int64), point_ids[np.asarray(i2, np.int64)]


def _refine(feat: Features, store: MapPointStore, group_pts: np.ndarray, camera: PinholeCamera, T_cw: np.ndarray,
            kp_idx: np.ndarray, pids: np.ndarray, radius: float, scale_factor: float, bf: float,
            check_distance: bool, max_distance: float = 64.0, ratio: float = 0.9) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Guided matching of ``group_pts`` at ``T_cw`` (keeping the given pairs), then pose refinement.
    Returns ``(T_cam_world, kp_idx, point_ids)`` of the inliers."""
    vis, proj, _ = project_local_points(store, group_pts, T_cw, camera, check_distance=check_distance)
    if len(vis):
        m, k, _ = guided_match(proj, store.descriptor[vis], feat.uv_undist, feat.descriptors, radius, True,
                               max_distance, ratio)
        # union with the given pairs (given ones win on conflicts)
        taken = np.zeros(len(feat.uv_undist), bool)
        taken[kp_idx] = True
        used = np.isin(vis[m], pids)
        keep = ~taken[k] & ~used
        kp_idx = np.concatenate([kp_idx, k[keep]])
        pids = np.concatenate([pids, vis[m][keep]])
    if len(kp_idx) < 6:
        return T_cw, kp_idx[:0], pids[:0]
    sigma = np.power(scale_factor, feat.octave[kp_idx].astype(float))
    ur = None if feat.u_right is None else feat.u_right[kp_idx]
    T_cw, inl = refine_pose(T_cw, store.position[pids], feat.uv_undist[kp_idx], camera.K, sigma, ur, bf)
    return T_cw, kp_idx[inl], pids[inl]


@dataclass(frozen=True)
class VerifyParams:
    """The thresholds of :func:`verify` (loop closing builds them from ``LoopClosingConfig``,
    relocalization from its own config).

    Attributes:
        ratio, max_distance: descriptor matching (ratio + mutual) of step 1.
        min_matches: fewest descriptor matches; RANSAC needs ``max(min_matches // 2, 6)`` inliers.
        align_threshold_m: 3D-3D inlier distance at 1 m depth (grows with ``z^2``), metric sensors.
        align_threshold_rel: monocular 3D-3D inlier distance, a fraction of the matched map points' median
            distance from their median point (the scene's extent; the scale is unknown).
        search_radius_px, min_search_radius_px: guided matching radius of round 1; round 2 uses
            ``max(search_radius_px / 2, min_search_radius_px)``.
        scale_factor: ORB pyramid scale (per-octave sigma of the refinement).
        bf: stereo baseline times focal length (0: no ``u_right`` residual).
        pnp_reproj_px: PnP RANSAC inlier threshold (frames without 3D points).
        seed: RANSAC seed.
        refine_ransac: refine the 3D-3D RANSAC pose on its inliers' reprojection errors (see :func:`verify`).
        guided_max_distance, guided_ratio: descriptor bounds of the guided matching.
    """

    ratio: float = 0.8
    max_distance: float = 64.0
    min_matches: int = 20
    align_threshold_m: float = 0.05
    align_threshold_rel: float = 0.09
    search_radius_px: float = 8.0
    scale_factor: float = 1.2
    bf: float = 0.0
    pnp_reproj_px: float = 4.0
    seed: int = 0
    refine_ransac: bool = False
    guided_max_distance: float = 64.0
    guided_ratio: float = 0.9
    min_search_radius_px: float = 3.0


@dataclass
class _Ransac:
    """A RANSAC pose ``T_cw`` (Sim(3) ``scale``) and its inlier pairs: keypoints ``kp``, points
    ``pids`` (-1: an extra candidate, not a map point) at world positions ``X``."""

    T_cw: np.ndarray
    scale: float
    n_ransac: int
    kp: np.ndarray
    pids: np.ndarray
    X: np.ndarray


def verify(feat: Features, store: MapPointStore, group_pts: np.ndarray, camera: PinholeCamera, sensor: str,
           params: VerifyParams | None = None, *, extra_X: np.ndarray | None = None,
           extra_desc: np.ndarray | None = None, extra_src: np.ndarray | None = None,
           extra_matches: dict[int, tuple[np.ndarray, np.ndarray]] | None = None,
           **overrides: Any) -> Verified | None:
    """Estimate the pose of ``feat`` against map points ``group_pts`` (ids into ``store``).

    1. descriptor matching (ratio + mutual) of the keypoints to the points;
    2. RANSAC: with ``feat.X_cam`` (depth, or the keyframe's own points) a 3D-3D alignment
       (:func:`align_points`, SE(3) for metric sensors, Sim(3) ``with_scale`` for monocular),
       otherwise PnP RANSAC (:func:`vslam.geometry.pnp.solve_pnp`);
    3. two rounds of guided matching by projection + robust pose refinement.

    ``params`` (:class:`VerifyParams`, default its defaults); keyword ``overrides`` replace single
    fields of it (``verify(..., ratio=0.7)``). ``guided_max_distance`` / ``guided_ratio``: descriptor
    bounds of the guided matching in 3, whose second round searches
    ``max(search_radius_px / 2, min_search_radius_px)``.

    ``refine_ransac``: between 2 and 3, the 3D-3D RANSAC pose is refined on its inliers' reprojection
    (and ``u_right``) errors (:func:`refine_pose`) and the pairs that fail its chi-square test are
    dropped; under 6 left, None. The closed-form fit weighs each pair's depth error (RGB-D noise grows
    with ``z^2``) like its image error, so with few inliers its pose is off by centimetres and
    degrees, too far for the guided matching of step 3 (TUM fr3/cabinet's loop, 21 RANSAC inliers:
    0.13 m / 4.4 deg from the ground-truth-implied pose, 0 map points found; refined 0.07 m / 2.0 deg,
    10 map-point inliers, final 0.015 m / 0.9 deg).

    ``extra_X (M, 3)`` / ``extra_desc (M, D)``: more candidates for the RANSAC stage that are not map
    points (e.g. keypoints of the candidate keyframes with measured depth, in world coordinates):
    with few map points (texture-poor scenes, wide baselines) they give RANSAC its support; the
    refinement then uses map points only. ``extra_src (M,)``: the keyframe each extra point comes
    from; the extras are then matched keyframe by keyframe (the ratio test within one keyframe, so the
    same scene point seen by several candidate keyframes is not rejected as ambiguous) and every
    pair enters the RANSAC (a query keypoint may match one point per keyframe: the candidate
    keyframes' poses are independent estimates, so their agreement is evidence).
    ``extra_matches``: a cache of those per-keyframe matches, ``{source: (kp_idx, index among that
    source's extras)}``, read and filled; pass the same dict only for the same query features and
    unchanged keyframes (the loop closer verifies a query against up to three overlapping groups).

    Returns None when any stage has too little support; the caller applies its own inlier threshold.
    """
    p = replace(params or VerifyParams(), **overrides)
    mono = sensor == "mono"
    if extra_X is not None and len(extra_X) and store.descriptor is not None:
        cands = _match_with_extras(feat, store, group_pts, extra_X, extra_desc, extra_src, p, extra_matches)
        if cands is None:
            return None
        kp, X_world, pids = cands
    else:
        kp, pids = descriptor_candidates(feat, store, group_pts, p.ratio, p.max_distance)
        X_world = store.position[pids]
    if len(kp) < p.min_matches:
        log.debug("verify: %d descriptor matches to %d points (< %d)", len(kp), len(group_pts), p.min_matches)
        return None
    ransac = _align_3d3d(feat, kp, X_world, pids, mono, p) if feat.X_cam is not None else None
    if ransac is not None and p.refine_ransac:
        ransac = _refine_ransac_pose(feat, camera, ransac, p)
        if ransac is None:
            return None
    if ransac is None:
        if mono and feat.X_cam is not None:
            return None  # monocular loops need the Sim(3) (scale) estimate
        ransac = _pnp_ransac(feat, camera, kp, X_world, pids, p)
        if ransac is None:
            return None
    on_map = ransac.pids >= 0  # refinement works on map points
    ransac.kp, ransac.pids = ransac.kp[on_map], ransac.pids[on_map]
    log.debug("verify: %d descriptor matches, %d RANSAC inliers", len(ransac.kp), ransac.n_ransac)
    return _guided_refinement(feat, store, group_pts, camera, ransac, mono, p)


def _match_with_extras(feat: Features, store: MapPointStore, group_pts: np.ndarray, extra_X: np.ndarray,
                       extra_desc: np.ndarray, extra_src: np.ndarray | None, p: VerifyParams,
                       cache: dict | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Step 1 with extra candidates: ``(kp_idx, X_world, point_ids)`` with point id -1 for an extra
    (matched keyframe by keyframe when ``extra_src`` is given), None without descriptors."""
    cand_X = np.concatenate([store.position[group_pts], extra_X])
    cand_desc = np.concatenate([store.descriptor[group_pts], extra_desc])
    cand_ids = np.concatenate([group_pts, np.full(len(extra_X), -1, np.int64)])
    if feat.descriptors is None or len(feat.descriptors) < 2 or len(cand_desc) < 2:
        return None
    if extra_src is None:
        i1, i2, _ = match_descriptors(feat.descriptors, cand_desc, binary=True, ratio=p.ratio, mutual=True,
                                      max_distance=p.max_distance)
        i1, i2 = np.asarray(i1, np.int64), np.asarray(i2, np.int64)
    else:
        i1, i2 = _match_per_keyframe(feat, cand_desc, len(group_pts), extra_desc, extra_src, p, cache)
    return i1, cand_X[i2], cand_ids[i2]


def _match_per_keyframe(feat: Features, cand_desc: np.ndarray, n_map: int, extra_desc: np.ndarray,
                        extra_src: np.ndarray, p: VerifyParams, cache: dict | None = None
                        ) -> tuple[np.ndarray, np.ndarray]:
    """Ratio + mutual matching against the map points, then against each source keyframe's extras
    alone (taken from / stored in ``cache`` by source when given); ``(kp_idx, candidate index)`` of
    all pairs (extras indexed after the ``n_map`` points)."""
    parts1, parts2 = [np.zeros(0, np.int64)], [np.zeros(0, np.int64)]
    if n_map >= 2:
        j1, j2, _ = match_descriptors(feat.descriptors, cand_desc[:n_map], binary=True, ratio=p.ratio,
                                      mutual=True, max_distance=p.max_distance)
        parts1.append(np.asarray(j1, np.int64))
        parts2.append(np.asarray(j2, np.int64))
    for src in np.unique(extra_src):
        sel = np.flatnonzero(extra_src == src)
        if len(sel) < 2:
            continue
        hit = None if cache is None else cache.get(int(src))
        if hit is None:
            j1, j2, _ = match_descriptors(feat.descriptors, extra_desc[sel], binary=True, ratio=p.ratio,
                                          mutual=True, max_distance=p.max_distance)
            hit = (np.asarray(j1, np.int64), np.asarray(j2, np.int64))
            if cache is not None:
                cache[int(src)] = hit
        parts1.append(hit[0])
        parts2.append(n_map + sel[hit[1]])
    return np.concatenate(parts1), np.concatenate(parts2)


def _align_3d3d(feat: Features, kp: np.ndarray, X_world: np.ndarray, pids: np.ndarray, mono: bool,
                p: VerifyParams) -> _Ransac | None:
    """Step 2 with 3D points: SE(3) (Sim(3) monocular) RANSAC of ``feat.X_cam[kp]`` onto ``X_world``;
    None with fewer than ``max(min_matches // 2, 6)`` valid pairs or inliers."""
    Xc = feat.X_cam[kp]
    ok = np.all(np.isfinite(Xc), axis=1)
    if ok.sum() < max(p.min_matches // 2, 6):
        return None
    src, dst = Xc[ok], X_world[ok]
    if mono:
        # inlier distance relative to the scene depth on the candidate side (scale unknown)
        d = np.linalg.norm(dst - np.median(dst, axis=0), axis=1)
        thr = p.align_threshold_rel * max(float(np.median(d)), 1e-6)
    else:
        z = np.maximum(1.0, src[:, 2])
        thr = p.align_threshold_m * float(np.median(z)) ** 2
    try:
        S, inl = align_points(src, dst, with_scale=mono, threshold=thr, seed=p.seed)
    except GeometryError:
        return None
    if inl.sum() < max(p.min_matches // 2, 6):
        return None
    scale = float(np.cbrt(np.linalg.det(S[:3, :3]))) if mono else 1.0
    T_wc = S.copy()
    T_wc[:3, :3] /= scale
    U, _, Vt = np.linalg.svd(T_wc[:3, :3])
    T_wc[:3, :3] = U @ Vt
    sel = np.flatnonzero(ok)[inl]
    return _Ransac(T_cw=inv_se3(T_wc), scale=scale, n_ransac=int(inl.sum()), kp=kp[sel], pids=pids[sel],
                   X=X_world[sel])


def _refine_ransac_pose(feat: Features, camera: PinholeCamera, r: _Ransac, p: VerifyParams) -> _Ransac | None:
    """The 3D-3D pose refined on its inliers' reprojection errors (:func:`refine_pose`); the pairs
    failing its chi-square test are dropped, None when fewer than 6 remain."""
    sig = np.power(p.scale_factor, feat.octave[r.kp].astype(float))
    ur = None if feat.u_right is None else feat.u_right[r.kp]
    T_cw, inl = refine_pose(r.T_cw, r.X, feat.uv_undist[r.kp], camera.K, sig, ur, p.bf)
    log.debug("verify: %d of %d RANSAC inliers consistent after reprojection refinement",
              int(inl.sum()), r.n_ransac)
    if inl.sum() < 6:
        return None
    return _Ransac(T_cw=T_cw, scale=r.scale, n_ransac=r.n_ransac, kp=r.kp[inl], pids=r.pids[inl], X=r.X[inl])


def _pnp_ransac(feat: Features, camera: PinholeCamera, kp: np.ndarray, X_world: np.ndarray, pids: np.ndarray,
                p: VerifyParams) -> _Ransac | None:
    """Step 2 without 3D points: PnP RANSAC (:func:`vslam.geometry.pnp.solve_pnp`), None on failure."""
    from vslam.geometry.pnp import solve_pnp

    try:
        T_cw, inl = solve_pnp(X_world, feat.uv_undist[kp], camera.K, threshold_px=p.pnp_reproj_px,
                              min_inliers=max(p.min_matches // 2, 6))
    except GeometryError:
        return None
    return _Ransac(T_cw=T_cw, scale=1.0, n_ransac=int(inl.sum()), kp=kp[inl], pids=pids[inl], X=X_world[inl])


def _guided_refinement(feat: Features, store: MapPointStore, group_pts: np.ndarray, camera: PinholeCamera,
                       r: _Ransac, mono: bool, p: VerifyParams) -> Verified:
    """Step 3: two rounds of guided matching + pose refinement from the RANSAC pose; with fewer
    than 6 map-point pairs left, the RANSAC pose with no map-point inliers."""
    T_cw, kp, pids = r.T_cw, r.kp, r.pids
    for radius in (p.search_radius_px, max(p.search_radius_px / 2.0, p.min_search_radius_px)):
        T_cw, kp, pids = _refine(feat, store, group_pts, camera, T_cw, kp, pids, radius, p.scale_factor, p.bf,
                                 check_distance=not mono, max_distance=p.guided_max_distance, ratio=p.guided_ratio)
        if len(kp) < 6:  # too few map points to refine: the RANSAC pose, no map-point inliers
            return Verified(T_world_cam=inv_se3(r.T_cw), scale=r.scale, kp_idx=kp[:0], point_ids=pids[:0],
                            n_inliers=0, n_ransac=r.n_ransac)
    log.debug("verify: %d inliers after guided matching", len(kp))
    return Verified(T_world_cam=inv_se3(T_cw), scale=r.scale, kp_idx=kp, point_ids=pids, n_inliers=len(kp),
                    n_ransac=r.n_ransac)
