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


def warm() -> None:
    """Load (or compile) the kernel on tiny inputs, so the first local BA pays nothing."""
    member_keypoints(np.array([0, -1, 1, 0], np.int64), np.array([True, False, False]), np.full(3, -1, np.int64), 0)
    i0 = np.zeros(1, np.int64)
    unit_ray_sums(np.ones((1, 3)), np.eye(4)[None].copy(), i0, i0, np.zeros((1, 3)), np.empty(1))
