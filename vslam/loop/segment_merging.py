"""Joining map segments when place recognition links them (ORB-SLAM3's Atlas, Campos et al., T-RO
2021, sec. VI-B): after tracking is lost and relocalization fails a new segment starts in its own
coordinate frame; when a keyframe of it is recognized in another (older) segment, the two are joined.

:func:`try_merge` is called by :meth:`vslam.loop.closing.LoopCloser.process` with the detector's
candidates that lie in *other* segments (a loop proper stays within one segment):

1. each candidate (at most ``closing.max_tries``) is verified as a loop would be
   (:meth:`LoopCloser._verify_group`: descriptor matching, 3D-3D RANSAC, SE(3) from depth or Sim(3)
   from the segment's own points for monocular, guided matching and pose refinement), accepted with
   ``min_inliers`` (``min_inliers_mono``) map-point inliers;
2. the query's segment moves into the matched one's world by ``S = S_world_cam(verified) T_cam_world``
   (monocular: the scale re-estimated on all verified inliers, :func:`_seam_similarity`; two
   gravity-aligned segments of a visual-inertial map: its yaw + translation only,
   :func:`vslam.map.pose_graph_4dof.yaw_correction`, and a segment whose IMU is not initialized yet
   waits for it before joining an aligned one;
   :func:`vslam.map.segment_merge.move_segment`; the older segment keeps its frame, so a continued
   map stays in the loaded map's world) and takes its id;
3. the seam is welded: the verified matches and the matched place's points projected into the
   query and its covisible keyframes are fused (:func:`vslam.map.segment_merge.fuse_seam`),
   covisibility is rebuilt, a local BA runs around the query (``closer.local_ba``) and then the
   global BA (``closer.global_ba``), as after a loop;
4. the merge is recorded (``closer.merges``, ``stats.json`` ``merges``) and ``merge_listeners``
   (the tracker) hear ``(old segment, new segment, S)``.
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from vslam.geometry.lie import inv_se3
from vslam.map.keyframe import KeyFrame
from vslam.map.pose_graph_4dof import yaw_correction
from vslam.map.segment_merge import fuse_seam, move_segment, similarity_scale

if TYPE_CHECKING:
    from vslam.loop.closing import LoopCloser

log = logging.getLogger(__name__)


@dataclass
class MergeRecord:
    """One joining of two segments: ``query_kf`` (of segment ``from_segment``) was recognized at
    ``match_kf`` (segment ``into_segment``); ``S`` maps the old segment's world into the new one's."""

    query_kf: int
    match_kf: int
    query_frame: int
    match_frame: int
    from_segment: int
    into_segment: int
    inliers: int
    scale: float
    moved_keyframes: int
    fused_points: int
    S: list
    ms: float = 0.0

    def to_json(self) -> dict:
        return dict(self.__dict__)


def try_merge(closer: "LoopCloser", kf: KeyFrame, candidates: list[int]) -> MergeRecord | None:
    """Verify ``candidates`` (keyframes of other segments) for ``kf`` and join the segments on the
    first accepted one (see the module docstring); None when none verifies."""
    cc = closer.config.closing
    need = cc.min_inliers_mono if closer.sensor == "mono" else cc.min_inliers
    t0 = time.perf_counter()
    aligned = closer.map.segment_gravity_aligned(kf.segment)
    for match_id in candidates[: cc.max_tries]:
        match = closer.map.keyframes.get(match_id)
        if match is None or match.bad or match.segment == kf.segment:
            continue
        if closer.map.segment_gravity_aligned(match.segment) != aligned and (closer.imu_pending or aligned):
            # one side is still in its visual world: while this run's IMU initialization is pending,
            # joining now would put keyframes of two sessions into one IMU initialization, so the join
            # waits for it; once it is done (a segment started after tracking was lost), the visual
            # segment joins the aligned one by the visual similarity, as without an IMU
            log.debug("merge candidate %d -> %d deferred: only one segment is gravity-aligned", kf.id, match_id)
            continue
        ver = closer._verify_group(kf, match_id)
        if ver is None or ver.n_inliers < need:
            log.debug("merge candidate %d -> %d rejected: %s inliers", kf.id, match_id,
                      None if ver is None else ver.n_inliers)
            continue
        return _join(closer, kf, match_id, ver, t0)
    return None


def _seam_similarity(closer: "LoopCloser", kf: KeyFrame, ver) -> np.ndarray:
    """``S_world_cam`` of the query in the matched segment's world. Monocular: the verified camera
    pose with the scale re-estimated on all verified inliers, the median of ``z_matched / z_query``
    (the matched points' depths in the verified camera over the query's own points' depths), when
    ``closing.merge_scale_min_pairs`` of them have a query point; the 3D-3D RANSAC's scale rests on
    its minimal-set inliers alone (10-11 on 7-Scenes, where 40-60 verified inliers have a depth).
    Like ORB-SLAM3's merge, which optimizes the Sim(3) on all matches (Campos et al. 2021, VI-B)."""
    if closer.sensor != "mono" or len(ver.kp_idx) == 0:
        return ver.S_world_cam
    z_query = closer.features_of(kf).X_cam[ver.kp_idx, 2]
    T = inv_se3(ver.T_world_cam)
    z_match = closer.map.points.position[ver.point_ids] @ T[2, :3] + T[2, 3]
    ok = np.isfinite(z_query) & (z_query > 0) & (z_match > 0)
    if ok.sum() < closer.config.closing.merge_scale_min_pairs:
        return ver.S_world_cam
    scale = float(np.median(z_match[ok] / z_query[ok]))
    log.debug("merge scale: RANSAC %.4f, median depth ratio of %d verified pairs %.4f", ver.scale, ok.sum(), scale)
    S = ver.T_world_cam.copy()
    S[:3, :3] *= scale
    return S


def _join(closer: "LoopCloser", kf: KeyFrame, match_id: int, ver, t0: float) -> MergeRecord:
    cc = closer.config.closing
    slam_map = closer.map
    match = slam_map.keyframes[match_id]
    src, dst = kf.segment, match.segment
    if slam_map.segment_gravity_aligned(src):  # both gravity-aligned (try_merge): yaw + translation only
        S = yaw_correction(kf.T_world_cam, ver.T_world_cam)
    else:
        S = _seam_similarity(closer, kf, ver) @ kf.T_cam_world  # query segment's world -> matched segment's world
    T_before = kf.T_world_cam.copy()
    moved = move_segment(slam_map, src, dst, S)
    seam = [kf.id] + [k for k in slam_map.covisible(kf.id, cc.candidate_neighbours) if k in set(moved)]
    place = [match_id] + [k for k in slam_map.covisible(match_id, cc.candidate_neighbours) if k not in set(moved)]
    fused = fuse_seam(slam_map, [(kf.id, ver.kp_idx, ver.point_ids)], seam, place, closer.camera, closer.sensor,
                      cc.fuse.radius_px, cc.fuse.max_descriptor_distance, cc.fuse.ratio)
    for k in sorted(set(moved) | set(place)):
        slam_map.update_covisibility(k)
    slam_map.loop_epoch += 1  # local BAs built before the move are stale
    for cb in closer.merge_listeners:
        cb(src, dst, S)
    closer._last_loop_kf = kf.id
    closer.detector.reset()
    if closer.local_ba is not None:
        closer.local_ba(kf.id)
    if closer.global_ba is not None and cc.global_ba:
        closer.global_ba()
    moved_by = float(np.linalg.norm(kf.T_world_cam[:3, 3] - T_before[:3, 3]))
    rec = MergeRecord(kf.id, match_id, kf.frame_index, match.frame_index, src, dst, ver.n_inliers,
                      round(similarity_scale(S), 4), len(moved), int(fused),
                      [[round(float(x), 6) for x in row] for row in S], round(1e3 * (time.perf_counter() - t0), 1))
    closer.merges.append(rec)
    log.info("segments joined: keyframe %d (frame %d, segment %d) recognized at keyframe %d (frame %d, segment %d), "
             "%d inliers, scale %.4f, %d keyframes moved %.2f m, %d points fused", kf.id, kf.frame_index, src,
             match_id, match.frame_index, dst, ver.n_inliers, rec.scale, len(moved), moved_by, fused)
    return rec
