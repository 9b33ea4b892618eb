"""Compiled (numba) kernel of :meth:`vslam.map.map.Map.update_covisibility`: the covisibility weight
of one keyframe pair, ``np.count_nonzero(flags[point_ids])`` (``-1``, no point, indexes the flag
array's last entry as in NumPy), in one pass without the gathered temporary."""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def count_flagged(flags, point_ids):  # pragma: no cover - compiled
    """``np.count_nonzero(flags[point_ids])`` (negative ids index from the end)."""
    n = flags.shape[0]
    c = 0
    for i in range(point_ids.shape[0]):
        p = point_ids[i]
        if flags[p if p >= 0 else p + n]:
            c += 1
    return c


def warm() -> None:
    """Call the kernel once on tiny inputs (loads the cached machine code)."""
    count_flagged(np.array([True, False]), np.array([0, -1], np.int64))
