"""Compiled (numba) kernels of :class:`vslam.backend.local_problem.LocalProblemBuilder` (which
keypoints of a keyframe observe the points of a local BA, one observation per point) and of the
write-back (:func:`unit_ray_sums`, :meth:`vslam.backend.map_writeback.PointWriteback.update_normals`).

It returns exactly the indices the NumPy expressions it replaces gave (``flatnonzero`` of the
member test, then each point's first keypoint kept through ``np.unique(..., return_index=True)``),
in one pass over the keyframe's ``point_ids`` instead of ~8 array expressions and a sort.
"""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def member_keypoints(point_ids, member, stamp, tag):  # pragma: no cover - compiled
    """Indices ``i`` (increasing) with ``point_ids[i] >= 0`` and ``member[point_ids[i]]``, each point
    once (its first keypoint). ``stamp``: a scratch array over the point ids whose entries equal to
    ``tag`` mark points already taken; give each keyframe of one build its own ``tag``."""
    out = np.empty(point_ids.shape[0], np.int64)
    n = 0
    for i in range(point_ids.shape[0]):
        p = point_ids[i]
        if p >= 0 and member[p] and stamp[p] != tag:
            stamp[p] = tag
            out[n] = i
            n += 1
    return out[:n]



@njit(cache=True, nogil=True)
def gather_keyframe(point_ids, member, stamp, tag, uv_undist, octave, depth, use_depth, out_pt, out_idx, out_uv,
                    out_oct, out_d, n0):  # pragma: no cover - compiled
    """:func:`member_keypoints` of one keyframe and the gathers of its selected keypoints in one pass:
    from row ``n0`` on, ``out_pt`` the point id, ``out_idx`` the keypoint index, ``out_uv`` the
    undistorted pixel, ``out_oct`` the octave and (``use_depth``) ``out_d`` the depth. Returns the
    next free row. The same values as ``point_ids[sel]``, ``uv_undist[sel]``, ... (copies)."""
    n = n0
    for i in range(point_ids.shape[0]):
        p = point_ids[i]
        if p >= 0 and member[p] and stamp[p] != tag:
            stamp[p] = tag
            out_pt[n] = p
            out_idx[n] = i
            out_uv[n, 0] = uv_undist[i, 0]
            out_uv[n, 1] = uv_undist[i, 1]
            out_oct[n] = octave[i]
            if use_depth:
                out_d[n] = depth[i]
            n += 1
    return n


@njit(cache=True, nogil=True)
def unit_ray_sums(X_world, T_world_cam, pt_row, kf_row, acc, dist):  # pragma: no cover - compiled
    """Per observation ``m`` the ray ``X_world[pt_row[m]] - centre(kf_row[m])``, its length into
    ``dist (M,)`` (``sqrt(x x + y y + z z)``, as ``row_norms``) and the unit ray (length floored at
    1e-12) summed per point into ``acc (P, 3)`` (zeros on entry) in observation order, as
    ``np.bincount(pt_row, weights=unit[:, c])`` sums it."""
    for m in range(pt_row.shape[0]):
        p = pt_row[m]
        k = kf_row[m]
        x = X_world[p, 0] - T_world_cam[k, 0, 3]
        y = X_world[p, 1] - T_world_cam[k, 1, 3]
        z = X_world[p, 2] - T_world_cam[k, 2, 3]
        d = np.sqrt(x * x + y * y + z * z)
        dist[m] = d
        s = d if not d < 1e-12 else 1e-12
        acc[p, 0] += x / s
        acc[p, 1] += y / s
        acc[p, 2] += z / s




@njit(cache=True, nogil=True)
def normals_and_ranges(X_world, T_world_cam, pt_row, kf_row, good, pt_ids, obs_sigma, normal, max_distance,
                       min_distance, acc, dist, last):  # pragma: no cover - compiled
    """All of :meth:`vslam.backend.map_writeback.PointWriteback.update_normals` in one pass, with the
    arithmetic of the NumPy code it replaced: :func:`unit_ray_sums` into ``acc (P, 3)`` (zeros on
    entry) and ``dist (M,)``, the per-point norm (``row_norms``), the normal ``acc / norm`` of the
    points that are ``good`` with ``norm > 1e-9``, and their distance range from their last
    observation ``o`` (``last (P,)`` scratch): ``max = dist[o] sigma[o]``, ``min = max / max(ratio, 1)``
    with the old ``ratio = old_max / max(old_min, 1e-12)`` (1 unless ``old_min > 0`` and ``old_max``
    is finite). ``normal``, ``max_distance``, ``min_distance``: the point store's arrays, written
    at rows ``pt_ids``."""
    unit_ray_sums(X_world, T_world_cam, pt_row, kf_row, acc, dist)
    for p in range(last.shape[0]):
        last[p] = -1
    for m in range(pt_row.shape[0]):
        last[pt_row[m]] = m
    for p in range(acc.shape[0]):
        a0, a1, a2 = acc[p, 0], acc[p, 1], acc[p, 2]
        norm = np.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
        if not (good[p] and norm > 1e-9):
            continue
        i = pt_ids[p]
        normal[i, 0] = a0 / norm
        normal[i, 1] = a1 / norm
        normal[i, 2] = a2 / norm
        o = last[p]
        if o < 0:
            continue
        old_max, old_min = max_distance[i], min_distance[i]
        ratio = 1.0
        if old_min > 0 and np.isfinite(old_max):
            ratio = old_max / (old_min if old_min >= 1e-12 else 1e-12)
        new_max = dist[o] * obs_sigma[o]
        max_distance[i] = new_max
        min_distance[i] = new_max / (ratio if ratio >= 1.0 else 1.0)



@njit(cache=True, nogil=True)
def unit_rays(position, pt, centre, kf, ray):  # pragma: no cover - compiled
    """Per observation ``m`` the unit viewing ray ``(position[pt[m]] - centre[kf[m]]) / max(|.|, 1e-12)``
    into ``ray (M, 3)``: the gathers, ``row_norms`` (``sqrt(x x + y y + z z)``) and the division of
    :func:`vslam.backend.local_problem.max_parallax_deg` in one pass, the same operations."""
    for m in range(pt.shape[0]):
        p = pt[m]
        k = kf[m]
        x = position[p, 0] - centre[k, 0]
        y = position[p, 1] - centre[k, 1]
        z = position[p, 2] - centre[k, 2]
        d = np.sqrt(x * x + y * y + z * z)
        s = d if not d < 1e-12 else 1e-12
        ray[m, 0] = x / s
        ray[m, 1] = y / s
        ray[m, 2] = z / s


@njit(cache=True, nogil=True)
def scatter_min(out, index, values):  # pragma: no cover - compiled
    """``np.minimum.at(out, index, values)``: ``out[index[m]] = minimum(out[index[m]], values[m])`` in
    order ``m``, NaN propagating as ``np.minimum`` does (a minimum is exact: the same bits, ~10x
    faster than the generic ``ufunc.at``)."""
    for m in range(index.shape[0]):
        p = index[m]
        v = values[m]
        if v < out[p] or v != v:
            out[p] = v


def warm() -> None:
    """Load (or compile) the kernels on tiny inputs, so the first local BA pays nothing."""
    member_keypoints(np.array([0, -1, 1, 0], np.int64), np.array([True, False, False]), np.full(3, -1, np.int64), 0)
    i0 = np.zeros(1, np.int64)
    unit_ray_sums(np.ones((1, 3)), np.eye(4)[None].copy(), i0, i0, np.zeros((1, 3)), np.empty(1))
    scatter_min(np.ones(1), i0, np.zeros(1))
    unit_rays(np.ones((1, 3)), i0, np.zeros((1, 3)), i0, np.empty((1, 3)))
    for use_depth in (True, False):
        gather_keyframe(np.array([0, -1], np.int64), np.array([True, False]), np.full(2, -1, np.int64), 0,
                        np.ones((2, 2)), np.zeros(2, np.int32), np.ones(2), use_depth, np.empty(2, np.int64),
                        np.empty(2, np.int64), np.empty((2, 2)), np.empty(2, np.int32), np.empty(2), 0)
    normals_and_ranges(np.ones((1, 3)), np.eye(4)[None].copy(), i0, i0, np.ones(1, np.bool_), i0, np.ones(1),
                       np.zeros((1, 3)), np.ones(1), np.ones(1), np.zeros((1, 3)), np.empty(1), np.empty(1, np.int64))
