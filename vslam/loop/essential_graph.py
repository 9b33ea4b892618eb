"""The essential graph of a loop correction: its construction from the map (spanning tree,
strong covisibility links, loop links) and the write-back of the solved poses to the keyframes and
map points. The solve itself is :func:`vslam.map.pose_graph.optimize_pose_graph` (Mur-Artal et al.,
T-RO 2015, sec. VII-D; Strasdat et al., RSS 2010 for Sim(3)), or in a gravity-aligned map
:func:`vslam.map.pose_graph_4dof.optimize_pose_graph_4dof` (position + yaw; Campos et al., T-RO
2021, sec. VI-C); the keyframes' IMU velocities turn with their corrections."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vslam.geometry.lie import inv_se3
from vslam.map.map import Map
from vslam.map.pose_graph import correct_points


@dataclass
class EssentialGraph:
    """Nodes (keyframe ids of one segment, sorted), their poses ``T_before (n, 4, 4)`` when built,
    the edges ``(i, j, T_i_j[, information])``, the initial poses (query side moved by the loop's
    correction) and the fixed node indices."""

    nodes: list[int]
    T_before: np.ndarray
    edges: list
    T_init: np.ndarray
    fixed: list[int]


def build_essential_graph(map_: Map, segment: int, match_id: int, q_group: list[int], c_group: list[int],
                          S_init: dict[int, np.ndarray], covisibility_edge_weight: int,
                          loop_edge_information: float) -> EssentialGraph:
    """The essential graph of ``segment``: each keyframe to its predecessor, covisibility links of
    weight >= ``covisibility_edge_weight`` (not across the loop), and loop edges from the candidate
    ``match_id`` to every query-side keyframe at its corrected pose ``S_init[k]``; the segment's
    first keyframe and the candidate are fixed."""
    nodes = sorted(k.id for k in map_.keyframes.values() if k.segment == segment)
    index = {k: i for i, k in enumerate(nodes)}
    T_before = np.stack([map_.keyframes[k].T_world_cam for k in nodes])
    edges = []
    prev = None
    for k in nodes:  # spanning tree: each keyframe to its predecessor in the segment
        if prev is not None:
            edges.append((index[prev], index[k], inv_se3(T_before[index[prev]]) @ T_before[index[k]]))
        prev = k
    qs, cs = set(q_group), set(c_group)
    for a in nodes:
        for b, w in map_.covisibility.get(a, {}).items():
            if b <= a or b not in index or w < covisibility_edge_weight or index[b] == index[a] + 1:
                continue
            if (a in qs and b in cs) or (a in cs and b in qs):
                continue  # links across the loop are given by the loop edges below
            edges.append((index[a], index[b], inv_se3(T_before[index[a]]) @ T_before[index[b]]))
    T_match = map_.keyframes[match_id].T_world_cam
    for k in q_group:  # loop edges: the candidate to every keyframe of the corrected query side
        edges.append((index[match_id], index[k], inv_se3(T_match) @ S_init[k], loop_edge_information))
    T_init = T_before.copy()
    for k in q_group:
        S = S_init[k]
        s = float(np.cbrt(np.linalg.det(S[:3, :3])))
        T_init[index[k]] = S
        T_init[index[k], :3, :3] /= s
    fixed = sorted({index[nodes[0]], index[match_id]})
    return EssentialGraph(nodes, T_before, edges, T_init, fixed)


def write_back_corrections(map_: Map, segment: int, nodes: list[int], T_before: np.ndarray,
                           S_after: np.ndarray) -> None:
    """Move the keyframes of ``segment`` and their points by the solved graph ``S_after (n, 4, 4)``.

    Each keyframe ``k`` moves by its node's correction ``S_k = S_after T_before^-1`` applied to its
    *current* pose (``S_k T_world_k``); keyframes created after the graph was built take the
    correction of the newest older node. Points move with their reference (first) keyframe
    (:func:`correct_points`); the poses keep their rotation, the Sim(3) scale is divided out.
    """
    C = S_after @ inv_se3(T_before)  # per-node correction (Sim(3) for monocular)
    now = sorted(k for k, f in map_.keyframes.items() if f.segment == segment)
    snap = np.asarray(nodes)
    node_of = np.searchsorted(snap, now, side="right") - 1  # the node itself, else the newest older one
    keep = node_of >= 0
    now = [k for k, ok in zip(now, keep) if ok]
    node_of = node_of[keep]
    T_now = np.stack([map_.keyframes[k].T_world_cam for k in now])
    S_now = C[node_of] @ T_now
    scales = np.cbrt(np.linalg.det(S_now[:, :3, :3]))
    T_after = S_now.copy()
    T_after[:, :3, :3] /= scales[:, None, None]
    store = map_.points
    n = len(store)
    ids = np.flatnonzero(store.alive[:n])
    ref = store.first_kf[ids]
    lut = np.full(max(now) + 2, -1, np.int64)
    lut[now] = np.arange(len(now))
    inseg = (ref >= 0) & (ref <= max(now))
    ids, ref = ids[inseg], lut[ref[inseg]]
    ids, ref = ids[ref >= 0], ref[ref >= 0]
    store.position[ids] = correct_points(store.position[ids], ref, T_now, S_now)
    for k, T in zip(now, T_after):
        map_.keyframes[k].T_world_cam = T.copy()
    rotate_velocities(map_, now, C[node_of])


def rotate_velocities(map_: Map, kf_ids: list[int], C: np.ndarray) -> None:
    """Visual-inertial keyframes: turn each ``extra["imu_velocity"]`` (world frame) with its
    keyframe's world correction ``C[i] (4, 4)`` (``v' = R_C v``; a pure yaw after a 4-DoF graph), as
    ORB-SLAM3 does after its 4-DoF essential graph. Keyframes without a velocity are left alone."""
    for k, Ck in zip(kf_ids, C):
        extra = map_.keyframes[k].extra
        v = extra.get("imu_velocity")
        if v is not None:
            R = Ck[:3, :3] / np.cbrt(np.linalg.det(Ck[:3, :3]))
            extra["imu_velocity"] = R @ v
