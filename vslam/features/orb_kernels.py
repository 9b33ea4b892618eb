"""Compiled (numba) kernels of the ORB detector's per-keypoint bookkeeping.

They compute exactly what the NumPy code they replace computed (integer sums, so no rounding
question arises), only without the temporaries: :func:`ic_moments` is the intensity-centroid
moments of :class:`vslam.features.orb_describe.Orientation` (ORB eq. 1-3) summed straight from the
image instead of through an integral image and fancy indexing, and :func:`grid_order` is
:func:`vslam.features.pyramid.grid_select`'s order for FAST's small integer scores by counting sorts.
"""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def ic_moments(img, x, y, umax, m01, m10):  # pragma: no cover - compiled
    """``m01[k] = sum dy * I``, ``m10[k] = sum dx * I`` over the disc rows ``|dx| <= umax[dy + r]``
    centred on ``(x[k], y[k])`` of the C-contiguous ``img`` (exact int64 sums, stored as float64;
    the disc is symmetric in ``dx`` and ``dy``, so these equal the row/column-segment sums of
    ``Orientation``). Rows ``+v`` and ``-v`` are walked together as in OpenCV's ``ICAngle``; the
    flat indices are unsigned so the inner loop has no negative-index branch."""
    r = (umax.shape[0] - 1) // 2
    f = img.reshape(-1)
    w = img.shape[1]
    for k in range(x.shape[0]):
        c = y[k] * w + x[k]
        a01 = np.int64(0)
        a10 = np.int64(0)
        u = umax[r]
        for dx in range(-u, u + 1):
            a10 += dx * np.int64(f[np.uint64(c + dx)])
        for v in range(1, r + 1):
            u = umax[r + v]
            s = np.int64(0)
            base_p = c + v * w
            base_m = c - v * w
            for dx in range(-u, u + 1):
                vp = np.int64(f[np.uint64(base_p + dx)])
                vm = np.int64(f[np.uint64(base_m + dx)])
                s += vp - vm
                a10 += dx * (vp + vm)
            a01 += v * s
        m01[k] = np.float64(a01)
        m10[k] = np.float64(a10)


@njit(cache=True, nogil=True)
def grid_order(cx, cy, score, n_keep):  # pragma: no cover - compiled
    """:func:`vslam.features.pyramid.grid_select` for small non-negative integer scores and
    non-negative cells ``(cx, cy)``: the indices ordered by (rank inside the cell, score
    descending, index), the first ``n_keep`` of them (all when ``n <= n_keep``, then by score
    descending, index). Three stable counting sorts instead of two comparison sorts; the order is
    the same total order, so the result is identical."""
    n = score.shape[0]
    smax = 0
    for i in range(n):
        smax = max(smax, score[i])
    # 1) by score descending, index ascending
    cnt = np.zeros(smax + 2, np.int64)
    for i in range(n):
        cnt[smax - score[i] + 1] += 1
    for b in range(1, smax + 2):
        cnt[b] += cnt[b - 1]
    by_score = np.empty(n, np.int64)
    for i in range(n):
        b = smax - score[i]
        by_score[cnt[b]] = i
        cnt[b] += 1
    if n <= n_keep:
        return by_score
    # 2) rank of every point inside its cell (cells visited in score order)
    ncx = 0
    ncy = 0
    for i in range(n):
        ncx = max(ncx, cx[i] + 1)
        ncy = max(ncy, cy[i] + 1)
    seen = np.zeros(ncx * ncy, np.int64)
    rank = np.empty(n, np.int64)
    rmax = 0
    for q in range(n):
        i = by_score[q]
        c = cy[i] * ncx + cx[i]
        rank[i] = seen[c]
        seen[c] += 1
        rmax = max(rmax, rank[i])
    # 3) by rank, then score order (stable)
    cnt = np.zeros(rmax + 2, np.int64)
    for i in range(n):
        cnt[rank[i] + 1] += 1
    for b in range(1, rmax + 2):
        cnt[b] += cnt[b - 1]
    out = np.empty(n, np.int64)
    for q in range(n):
        i = by_score[q]
        out[cnt[rank[i]]] = i
        cnt[rank[i]] += 1
    return out[:max(n_keep, 0)]


def warm() -> None:
    """Call every kernel once on tiny inputs (so the first real call pays no load or compile)."""
    img = np.zeros((8, 8), np.uint8)
    m = np.zeros(1, np.float64)
    ic_moments(img, np.array([3], np.int64), np.array([3], np.int64), np.array([1, 2, 1], np.int64), m, m.copy())
    z = np.zeros(2, np.int64)
    grid_order(z, z, z, 1)
