"""Poses of the frames between keyframes after the backend moved the keyframes.

Tracking gives every frame a pose against the map; only keyframes are optimized (local BA, loop
correction, global BA). ORB-SLAM stores each frame relative to its reference keyframe and re-expresses
it through that keyframe's corrected pose (``T_world_cam = T_world_kf T_kf_cam``): a frame moves
rigidly with the keyframe *before* it, and the frame just before the next keyframe, one frame of
tracking away from it, ignores that keyframe's correction. The trajectory then saw-tooths against the
corrected keyframes.

``interpolate``: frame ``i`` between keyframes ``a`` and ``b`` (timestamps ``t_a <= t_i < t_b``, same
map segment) takes the correction ``D_a = T_a(now) T_a(recorded)^-1`` of ``a`` (as recorded with the
frame) blended towards the correction ``D_b = T_b(now) T_b(inserted)^-1`` of ``b`` by the time fraction
``s = (t_i - t_a) / (t_b - t_a)``:

    D(s) = D_a [Exp(s phi) | s t],   (phi, t) = (Log R, t) of D_a^-1 D_b

(rotation slerp and linear translation of the relative correction; ``D(0) = D_a``, ``D(1) = D_b``), and
``T_world_cam = D(s) T_world_cam(recorded)``. Without a backend every correction is the identity and
the tracked poses come back unchanged. Frames after the last keyframe, before the first one or
referenced to an older keyframe (relocalization) follow their reference keyframe rigidly.
"""
from __future__ import annotations

from typing import Mapping

import numpy as np

from vslam.geometry.lie import inv_se3, slerp_rotation
from vslam.map.keyframe import KeyFrame


def blend_corrections(D_a: np.ndarray, D_b: np.ndarray, s: np.ndarray) -> np.ndarray:
    """``D_a [Exp(s phi) | s t]`` with ``(phi, t)`` of ``D_a^-1 D_b``, vectorized over ``(N, 4, 4)``."""
    rel = inv_se3(D_a) @ D_b
    E = np.tile(np.eye(4), (len(s), 1, 1))
    E[:, :3, :3] = slerp_rotation(np.eye(3), rel[:, :3, :3], s)
    E[:, :3, 3] = s[:, None] * rel[:, :3, 3]
    return D_a @ E


def frame_poses(timestamps: np.ndarray, ref_ids: np.ndarray, T_world_cam_rec: np.ndarray,
                T_world_ref_rec: np.ndarray, keyframes: Mapping[int, KeyFrame],
                T_world_kf_inserted: Mapping[int, np.ndarray], interpolate: bool = True) -> np.ndarray:
    """Current pose of every recorded frame (see the module docstring).

    Args:
        timestamps: ``(N,)`` frame times.
        ref_ids: ``(N,)`` reference keyframe id of each frame when it was tracked, -1 for none.
        T_world_cam_rec: ``(N, 4, 4)`` the tracked pose as recorded.
        T_world_ref_rec: ``(N, 4, 4)`` the reference keyframe's pose when the frame was recorded
            (ignored where ``ref_ids`` is -1).
        keyframes: the map's keyframes (current poses, timestamps, segments).
        T_world_kf_inserted: each keyframe's pose when it was inserted (keyframes missing here are
            not interpolation targets).
        interpolate: False gives ORB-SLAM's rigid re-expression through the reference keyframe only.

    Returns:
        ``(N, 4, 4)`` ``T_world_cam``.
    """
    T = np.array(T_world_cam_rec, dtype=float, copy=True)
    ref_ids = np.asarray(ref_ids, np.int64)
    timestamps = np.asarray(timestamps, float)
    has = np.flatnonzero((ref_ids >= 0) & np.isin(ref_ids, np.fromiter(keyframes, np.int64, len(keyframes))))
    if len(has) == 0:
        return T
    T_ref_now = np.stack([keyframes[int(r)].T_world_cam for r in ref_ids[has]])
    D = T_ref_now @ inv_se3(np.asarray(T_world_ref_rec, float)[has])  # rigid: T_world_kf T_kf_cam
    if interpolate:
        targets = sorted((k.segment, k.timestamp, k.id) for k in keyframes.values() if k.id in T_world_kf_inserted)
        if targets:
            seg = np.array([t[0] for t in targets], np.int64)
            ts = np.array([t[1] for t in targets])
            ids = np.array([t[2] for t in targets], np.int64)
            ref_seg = np.array([keyframes[int(r)].segment for r in ref_ids[has]], np.int64)
            # targets sorted by (segment, time): position of the frame among its segment's keyframes
            key = np.lexsort((ts, seg))
            seg, ts, ids = seg[key], ts[key], ids[key]
            t_i = timestamps[has]
            lo = np.searchsorted(seg, ref_seg, side="left")
            hi = np.searchsorted(seg, ref_seg, side="right")
            # one sorted key (segment, time): the last keyframe at or before t_i within the segment
            t0 = min(float(ts.min()), float(t_i.min()))
            span = 10.0 * (max(float(ts.max()), float(t_i.max())) - t0) + 1.0
            pos = np.searchsorted(seg * span + (ts - t0), ref_seg * span + (t_i - t0), side="right") - 1
            nxt = pos + 1
            ok = (pos >= lo) & (nxt < hi)
            ok[ok] &= ids[pos[ok]] == ref_ids[has][ok]  # the frame hangs on the latest keyframe before it
            if np.any(ok):
                b = ids[nxt[ok]]
                t_a = np.array([keyframes[int(r)].timestamp for r in ref_ids[has][ok]])
                t_b = ts[nxt[ok]]
                s = np.clip((t_i[ok] - t_a) / np.maximum(t_b - t_a, 1e-12), 0.0, 1.0)
                T_b_now = np.stack([keyframes[int(k)].T_world_cam for k in b])
                T_b_ins = np.stack([T_world_kf_inserted[int(k)] for k in b])
                D[ok] = blend_corrections(D[ok], T_b_now @ inv_se3(T_b_ins), s)
    T[has] = D @ T[has]
    return T
