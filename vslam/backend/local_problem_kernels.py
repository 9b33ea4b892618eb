"""Compiled (numba) kernel of :class:`vslam.backend.local_problem.LocalProblemBuilder`: which
keypoints of a keyframe observe the points of a local BA, one observation per point.

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


def warm() -> None:
    """Load (or compile) the kernel on tiny inputs, so the first local BA pays nothing."""
    member_keypoints(np.array([0, -1, 1, 0], np.int64), np.array([True, False, False]), np.full(3, -1, np.int64), 0)
