"""Append one map into another under a similarity transform (the data step of map merging).

:func:`append_map` copies every keyframe, map point and covisibility link of ``src`` into ``dst``,
mapped into ``dst``'s world by ``S_dst_src = [s R, t; 0, 1]`` (``X_dst = s R X_src + t``; ``s = 1``
for metric sensors, the Sim(3) scale for monocular maps):

* keyframe ids are shifted past ``dst``'s (``dst.next_keyframe_id()``), point ids past its store, so
  nothing of ``dst`` is renumbered and ``src``'s ids map by one offset each;
* poses: ``T' = [R_S R, s R_S t + t_S; 0, 1]`` (the camera stays rigid, its centre moves with the
  points: ``S T`` with the scale taken out of the rotation), measured depths scale with ``s``;
* segments: ``segment_map`` renames ``src``'s segments (a joined segment takes the ``dst`` segment it
  was welded into; the rest get new ids past ``dst``'s);
* the segment table (:mod:`vslam.map.segments`) gets one row per ``src`` segment, with its source
  name, id range and ``S_dst_src`` composed with the row's own transform.

Nothing is matched or optimized here: duplicates across the seam are fused and the seam welded by the
caller (:mod:`vslam.merge`).
"""
from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np

from vslam.map.map import Map
from vslam.map.segments import SegmentRecord, segment_table


@dataclass
class AppendResult:
    """Where ``src``'s ids went: keyframe ``k`` -> ``k + kf_offset``, point ``p`` -> ``p + point_offset``,
    segment ``s`` -> ``segment_map[s]``."""

    kf_offset: int
    point_offset: int
    segment_map: dict[int, int]


def append_map(dst: Map, src: Map, S_dst_src: np.ndarray, *, source: str = "",
               segment_map: dict[int, int] | None = None) -> AppendResult:
    """Append ``src`` into ``dst`` (modified in place; ``src`` is not) mapped by ``S_dst_src``.

    Args:
        dst, src: the maps.
        S_dst_src: ``(4, 4)`` Sim(3) from ``src``'s world to ``dst``'s.
        source: a name for ``src`` recorded in the segment table (e.g. its folder).
        segment_map: ``{src segment: dst segment}`` for the segments to join; the others get fresh ids.
    """
    S = np.asarray(S_dst_src, dtype=float)
    s = float(np.cbrt(np.linalg.det(S[:3, :3])))
    R_S = S[:3, :3] / s
    dst_table = segment_table(dst)
    src_table = segment_table(src)
    kf_offset = max(dst.next_keyframe_id(), max(dst.keyframes, default=-1) + 1)
    next_seg = 1 + max([k.segment for k in dst.keyframes.values()] + [r.segment for r in dst_table], default=-1)
    seg_map = dict(segment_map or {})
    for seg in sorted({k.segment for k in src.keyframes.values()} | {r.segment for r in src_table}):
        if seg not in seg_map:
            seg_map[seg] = next_seg
            next_seg += 1
    point_offset = dst.points.append_store(src.points, S, kf_offset)
    for kid, kf in src.keyframes.items():
        new = copy.copy(kf)
        new.id = kid + kf_offset
        T = kf.T_world_cam
        new.T_world_cam = np.eye(4)
        new.T_world_cam[:3, :3] = R_S @ T[:3, :3]
        new.T_world_cam[:3, 3] = S[:3, :3] @ T[:3, 3] + S[:3, 3]
        new.point_ids = np.where(kf.point_ids >= 0, kf.point_ids + point_offset, -1)
        new.depth = kf.depth * s if s != 1.0 else kf.depth.copy()
        new.segment = seg_map[kf.segment]
        new.extra = copy.deepcopy(kf.extra)
        new.__dict__.pop("_keypoint_tree", None)
        dst.keyframes[new.id] = new
    for kid, links in src.covisibility.items():
        dst.covisibility[kid + kf_offset] = {j + kf_offset: w for j, w in links.items()}
    dst._next_kf_id = max(dst._next_kf_id, src.next_keyframe_id() + kf_offset)
    rows = [] if dst.segments else dst_table
    for r in src_table:
        lo, hi = r.keyframe_ids
        rows.append(SegmentRecord(seg_map[r.segment], r.source or source, r.source_segment,
                                  (lo + kf_offset, hi + kf_offset), S @ r.S_segment_source))
    dst.segments = list(dst.segments) + rows
    return AppendResult(kf_offset, point_offset, seg_map)
