"""Compiled (numba) kernels of the ORB detector's per-keypoint bookkeeping.

They compute exactly what the NumPy code they replace computed (integer sums, so no rounding
question arises), only without the temporaries: :func:`ic_moments` is the intensity-centroid
moments of :class:`vslam.features.orb_describe.Orientation` (ORB eq. 1-3) summed straight from the
image instead of through an integral image and fancy indexing.
"""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def ic_moments(img, x, y, umax, m01, m10):  # pragma: no cover - compiled
    """``m01[k] = sum dy * I``, ``m10[k] = sum dx * I`` over the disc rows ``|dx| <= umax[dy + r]``
    centred on ``(x[k], y[k])`` (exact int64 sums, stored as float64; the disc is symmetric in
    ``dx`` and ``dy``, so these equal the row/column-segment sums of ``Orientation``)."""
    r = (umax.shape[0] - 1) // 2
    for k in range(x.shape[0]):
        cx = x[k]
        cy = y[k]
        a01 = np.int64(0)
        a10 = np.int64(0)
        for i in range(2 * r + 1):
            dy = i - r
            u = umax[i]
            row = img[cy + dy]
            s = np.int64(0)
            sx = np.int64(0)
            for dx in range(-u, u + 1):
                v = np.int64(row[cx + dx])
                s += v
                sx += dx * v
            a01 += dy * s
            a10 += sx
        m01[k] = np.float64(a01)
        m10[k] = np.float64(a10)


def warm() -> None:
    """Call every kernel once on tiny inputs (so the first real call pays no load or compile)."""
    img = np.zeros((8, 8), np.uint8)
    m = np.zeros(1, np.float64)
    ic_moments(img, np.array([3], np.int64), np.array([3], np.int64), np.array([1, 2, 1], np.int64), m, m.copy())
