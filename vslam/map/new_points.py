"""New map points for a new monocular keyframe, by triangulation with earlier keyframes, and the
point culling that follows a keyframe insertion (ORB-SLAM's LocalMapping: CreateNewMapPoints and
the found-ratio test of MapPointCulling, Mur-Artal et al. 2015, sec. VI-B/C).

Local mapping (:class:`vslam.backend.local_mapping.LocalMapper`) runs :class:`KeyframeMapping` on
each new keyframe as it arrives; without a graph backend the System runs it alone. The tracker
marks in ``kf.extra`` what it needs: ``triangulate`` (monocular keyframes that want new points)
and, for KLT tracks, ``anchor_kf`` / ``anchor_idx`` (the keyframe and keypoint each track was
born at; triangulated against that keyframe). With descriptors the unmatched keypoints are matched
with those of the ``triangulation_keyframes`` previous keyframes of the segment.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vslam.geometry.triangulation import ray_parallax_deg, reprojection_error_depth, triangulate
from vslam.map.keyframe import KeyFrame
from vslam.map.map import Map
from vslam.map.matching import brute_force_match


@dataclass(frozen=True)
class NewPointsParams:
    """Settings of point creation and culling (the frontend's ``mono.*`` and ``local_map.*``).

    Attributes:
        K: ``(3, 3)`` intrinsics (undistorted keypoints).
        scale_factor, max_level_scale: feature pyramid scale and ``scale_factor ** (n_levels - 1)``.
        binary: binary descriptors (Hamming distance).
        triangulation_keyframes: previous keyframes matched (descriptor association).
        match_ratio: ratio test of those matches; max_descriptor_distance: their bound (binary).
        max_reproj_sigmas: reprojection error bound in octave sigmas; min_parallax_deg: ray angle bound.
        cull_min_found_ratio: points found in fewer than this ratio of the frames they were visible in die.
        max_map_points, local_keyframes: beyond ``max_map_points`` the points outside the new
            keyframe's ``local_keyframes`` most covisible ones, oldest first, are dropped.
    """

    K: np.ndarray
    scale_factor: float = 1.2
    max_level_scale: float = 1.0
    binary: bool = True
    triangulation_keyframes: int = 2
    match_ratio: float = 0.8
    max_descriptor_distance: float | None = None
    max_reproj_sigmas: float = 2.0
    min_parallax_deg: float = 1.0
    cull_min_found_ratio: float = 0.25
    max_map_points: int = 200_000
    local_keyframes: int = 10


class KeyframeMapping:
    """``on_keyframe(kf)``: new monocular points, then point culling (see the module docstring)."""

    def __init__(self, map_: Map, params: NewPointsParams) -> None:
        self.map = map_
        self.params = params

    def on_keyframe(self, kf: KeyFrame) -> None:
        if kf.extra.get("triangulate"):
            if triangulate_new_points(self.map, kf, self.params):
                self.map.covisibility[kf.id] = {}
                self.map.update_covisibility(kf.id)
        self.map.cull_points(self.params.cull_min_found_ratio)
        if self.map.points.n_alive > self.params.max_map_points:
            self.map.limit_points(self.params.max_map_points, self.map.local_keyframes(kf.id, self.params.local_keyframes))


def triangulate_new_points(map_: Map, kf: KeyFrame, p: NewPointsParams) -> int:
    """Triangulate unmatched keypoints of ``kf`` (in the map) with earlier keyframes: KLT tracks
    with their birth keyframe (``kf.extra['anchor_kf']``), else descriptor matches with the
    previous keyframes of the segment, newest first. Returns the number of new points."""
    n = 0
    anchors = kf.extra.get("anchor_kf")
    if anchors is None:
        olds = sorted((k for k in map_.keyframes.values() if k.segment == kf.segment and k.id < kf.id),
                      key=lambda k: -k.id)[: p.triangulation_keyframes]
        for old in olds:
            a = np.flatnonzero(old.point_ids < 0)
            b = np.flatnonzero(kf.point_ids < 0)
            if len(a) < 8 or len(b) < 8:
                continue
            i1, i2 = brute_force_match(old.descriptors[a], kf.descriptors[b], p.binary, ratio=p.match_ratio,
                                       max_distance=p.max_descriptor_distance if p.binary else None)
            n += triangulate_pairs(map_, old, a[i1], kf, b[i2], p)
        return n
    anchor_idx = kf.extra["anchor_idx"]
    cand = np.flatnonzero((kf.point_ids < 0) & (anchors >= 0) & (anchors != kf.id))
    for a_id in np.unique(anchors[cand]):
        if a_id not in map_.keyframes:
            continue
        sel = cand[anchors[cand] == a_id]
        n += triangulate_pairs(map_, map_.keyframes[int(a_id)], anchor_idx[sel], kf, sel, p)
    return n


def triangulate_pairs(map_: Map, kf1: KeyFrame, idx1: np.ndarray, kf2: KeyFrame, idx2: np.ndarray,
                      p: NewPointsParams) -> int:
    """New points from keypoints ``idx1`` of ``kf1`` matched to ``idx2`` of ``kf2`` (the newer one,
    already in the map): linear triangulation (Hartley & Zisserman 12.2), kept when in front of both
    cameras, within ``max_reproj_sigmas`` octave sigmas in both and with a ray angle above
    ``min_parallax_deg``. Both keyframes observe the new points; returns how many."""
    if len(idx1) < 1:
        return 0
    ok1 = kf1.point_ids[idx1] < 0
    idx1, idx2 = idx1[ok1], idx2[ok1]
    if len(idx1) == 0:
        return 0
    T1, T2 = kf1.T_cam_world, kf2.T_cam_world
    x1, x2 = kf1.uv_undist[idx1], kf2.uv_undist[idx2]
    X = triangulate(T1, T2, p.K, x1, x2)
    e1, z1 = reprojection_error_depth(T1, p.K, X, x1)
    e2, z2 = reprojection_error_depth(T2, p.K, X, x2)
    s1 = np.power(p.scale_factor, kf1.octave[idx1].astype(float))
    s2 = np.power(p.scale_factor, kf2.octave[idx2].astype(float))
    par = ray_parallax_deg(kf1.T_world_cam, kf2.T_world_cam, X)
    good = np.all(np.isfinite(X), axis=1) & (z1 > 0) & (z2 > 0) & (e1 < p.max_reproj_sigmas * s1) \
        & (e2 < p.max_reproj_sigmas * s2) & (par > p.min_parallax_deg)
    if not good.any():
        return 0
    # a keypoint index may appear twice (KLT duplicates): keep the first
    _, first = np.unique(idx2[good], return_index=True)
    g = np.flatnonzero(good)[first]
    desc = None if kf2.descriptors is None else kf2.descriptors[idx2[g]]
    ids = map_.points.add(X[g], desc, kf2.T_world_cam[:3, 3], kf2.id,
                          np.power(p.scale_factor, kf2.octave[idx2[g]].astype(float)), p.max_level_scale)
    kf2.point_ids[idx2[g]] = ids
    kf1.point_ids[idx1[g]] = ids
    map_.points.n_obs[ids] += 1  # kf1's observation (kf2's came with the point)
    return len(ids)
