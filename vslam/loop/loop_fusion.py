"""Point fusion of an accepted loop: the candidate side's map points replace the query side's
duplicates in every query-side keyframe (ORB-SLAM's CorrectLoop + SearchAndFuse, Mur-Artal et al.,
T-RO 2015, sec. VII-C)."""
from __future__ import annotations

import numpy as np

from vslam.geometry.camera import PinholeCamera
from vslam.geometry.lie import inv_se3
from vslam.loop.config import ClosingConfig
from vslam.loop.verification import Verified
from vslam.map.fusion import apply_remap, assign_observations, new_remap
from vslam.map.keyframe import KeyFrame
from vslam.map.map import Map
from vslam.map.matching import guided_match, project_local_points


def fuse_loop_points(map_: Map, camera: PinholeCamera, sensor: str, cc: ClosingConfig, kf: KeyFrame,
                     ver: Verified, q_group: list[int], c_group: list[int], S_init: dict[int, np.ndarray]) -> int:
    """Fuse the loop's duplicated points: the candidate-side point survives, the query-side one
    is replaced in every keyframe: the verified pairs of ``kf``, then the candidate group's points
    projected into each query-side keyframe at its corrected pose ``S_init[k]`` (Sim(3), the scale
    divided out). Returns the number of query-side points removed."""
    store = map_.points
    n = len(store)
    remap = new_remap(n)
    n_fused = assign_observations(map_, kf, ver.kp_idx, ver.point_ids, remap)
    c_pts = map_.local_point_ids(c_group)
    for k in q_group:
        if k == kf.id:
            continue
        other = map_.keyframes[k]
        if other.descriptors is None or other.descriptors.dtype != np.uint8:
            continue
        S = S_init[k]
        s = float(np.cbrt(np.linalg.det(S[:3, :3])))
        T = S.copy()
        T[:3, :3] /= s
        vis, proj, _ = project_local_points(store, c_pts[store.alive[c_pts]], inv_se3(T), camera,
                                            check_distance=sensor != "mono")
        if len(vis) == 0:
            continue
        m, kp, _ = guided_match(proj, store.descriptor[vis], other.uv_undist, other.descriptors,
                                cc.fuse.radius_px, True, cc.fuse.max_descriptor_distance, cc.fuse.ratio)
        n_fused += assign_observations(map_, other, kp, vis[m], remap)
    if n_fused:
        apply_remap(map_.keyframes.values(), remap)
    return n_fused
