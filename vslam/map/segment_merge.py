"""Joining two segments of one map (ORB-SLAM3's Atlas merging, Campos et al., T-RO 2021, sec. VI-B):
the data steps shared by loop closing (segments of one run meeting) and offline map merging.

* :func:`move_segment`: every keyframe and map point of segment ``src`` is mapped into the world
  of segment ``dst`` by the similarity ``S_dst_src = [s R, t; 0, 1]`` (``X' = s R X + t``; ``s = 1``
  for metric sensors) and relabelled ``dst``. A pose moves as the camera centre does and stays
  rigid: ``T' = [R_S R, s R_S t + t_S; 0, 1]``; measured depths scale with ``s``. The segment
  table (:mod:`vslam.map.segments`) keeps one row per piece, the moved rows with ``S_dst_src``
  composed into their transform. A keyframe's IMU velocity (``extra["imu_velocity"]``, world frame)
  becomes ``s R v``. Between gravity-aligned segments ``S_dst_src`` is a yaw + translation
  (:func:`vslam.map.pose_graph_4dof.yaw_correction`), so the moved segment stays gravity-aligned.
* :func:`fuse_seam`: duplicates across the seam are fused: the verified matches, then the map
  points of the matched place projected into the seam keyframes and fused (ORB-SLAM's
  SearchAndFuse; the ``dst`` point survives).

The local BA around the seam and the global BA / pose graph are the caller's (a stage above).
"""
from __future__ import annotations

import numpy as np

from vslam.geometry.camera import PinholeCamera
from vslam.geometry.lie import inv_se3
from vslam.map.fusion import apply_remap, assign_observations, new_remap
from vslam.map.map import Map
from vslam.map.matching import guided_match, project_local_points
from vslam.map.segments import SegmentRecord, segment_table


def similarity_scale(S: np.ndarray) -> float:
    """``s`` of ``S = [s R, t; 0, 1]``."""
    return float(np.cbrt(np.linalg.det(np.asarray(S, float)[:3, :3])))


def move_pose(S: np.ndarray, T_world_cam: np.ndarray) -> np.ndarray:
    """The rigid pose ``[R_S R, s R_S t + t_S]`` of a camera whose world moved by ``S``."""
    s = similarity_scale(S)
    out = np.eye(4)
    out[:3, :3] = (S[:3, :3] / s) @ T_world_cam[:3, :3]
    out[:3, 3] = S[:3, :3] @ T_world_cam[:3, 3] + S[:3, 3]
    return out


def move_segment(slam_map: Map, src: int, dst: int, S_dst_src: np.ndarray) -> list[int]:
    """Map segment ``src`` into segment ``dst``'s world by ``S_dst_src`` and relabel it ``dst`` (see the
    module docstring). Returns the moved keyframe ids. Points observed by ``src``'s keyframes move
    (segments share no points before they are joined)."""
    S = np.asarray(S_dst_src, dtype=float)
    s = similarity_scale(S)
    R = S[:3, :3] / s
    if not slam_map.segments:  # a one-run map: record its rows before they stop being derivable
        slam_map.segments = segment_table(slam_map)
    moved = sorted(k for k, kf in slam_map.keyframes.items() if kf.segment == src)
    store = slam_map.points
    pids = slam_map.local_point_ids(moved)
    pids = pids[(pids >= 0) & (pids < len(store))]
    store.position[pids] = store.position[pids] @ S[:3, :3].T + S[:3, 3]
    store.normal[pids] = store.normal[pids] @ R.T
    store.min_distance[pids] *= s
    store.max_distance[pids] *= s
    for k in moved:
        kf = slam_map.keyframes[k]
        kf.T_world_cam = move_pose(S, kf.T_world_cam)
        if s != 1.0 and kf.depth is not None:
            kf.depth = kf.depth * s
        if "imu_velocity" in kf.extra:  # visual-inertial: the world-frame velocity turns (and scales) too
            kf.extra["imu_velocity"] = S[:3, :3] @ kf.extra["imu_velocity"]
        kf.segment = dst
    slam_map.segments = [SegmentRecord(dst, r.source, r.source_segment, r.keyframe_ids, S @ r.S_segment_source)
                         if r.segment == src else r for r in slam_map.segments]
    return moved


def fuse_seam(slam_map: Map, matches: list[tuple[int, np.ndarray, np.ndarray]], seam_kf_ids: list[int],
              place_kf_ids: list[int], camera: PinholeCamera, sensor: str, radius_px: float,
              max_distance: int, ratio: float) -> int:
    """Fuse the seam's duplicates: ``matches`` ``(kf_id, keypoint indices, point ids)`` (the verified
    inliers: the keypoints take those points), then the points of ``place_kf_ids`` (the matched
    place) projected into each of ``seam_kf_ids`` and matched by descriptor within ``radius_px``
    (``max_distance`` bits, ``ratio``). The place's point survives. Returns the points merged away."""
    store = slam_map.points
    remap = new_remap(len(store))
    fused = 0
    for kf_id, kp, pid in matches:
        fused += assign_observations(slam_map, slam_map.keyframes[kf_id], kp, pid, remap)
    place_pts = slam_map.local_point_ids(place_kf_ids)
    for k in seam_kf_ids:
        kf = slam_map.keyframes.get(k)
        if kf is None or kf.bad or kf.descriptors is None or kf.descriptors.dtype != np.uint8:
            continue
        pts = place_pts[store.alive[place_pts]]
        vis, proj, _ = project_local_points(store, pts, inv_se3(kf.T_world_cam), camera,
                                            check_distance=sensor != "mono")
        if len(vis) == 0:
            continue
        mi, kp, _ = guided_match(proj, store.descriptor[vis], kf.uv_undist, kf.descriptors, radius_px, True,
                                 max_distance, ratio)
        fused += assign_observations(slam_map, kf, kp, vis[mi], remap)
    apply_remap(slam_map.keyframes.values(), remap)
    return fused
