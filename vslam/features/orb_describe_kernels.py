"""Compiled (numba) rotated-BRIEF descriptors of ORB (Rublee et al., ICCV 2011, Sec. 4), bit for bit
those of ``cv2.ORB.compute`` for keypoints on one level (``nlevels=1``), without building a list of
``cv2.KeyPoint`` or OpenCV's padded pyramid buffer.

For a keypoint at integer ``(cx, cy)`` with angle ``theta`` (degrees, float32) the pattern point
``(px, py)`` is rotated, ``x = px cos - py sin``, ``y = px sin + py cos`` (ORB eq. 4-5), rounded to
the nearest pixel and read from the level image smoothed by a 7 x 7, sigma 2 Gaussian; bit ``j`` of
byte ``i`` is ``I(p_{2k}) < I(p_{2k+1})`` for pair ``k = 8 i + j``. To be OpenCV's result exactly the
arithmetic is OpenCV's: ``theta`` is turned into radians in float32 (times float32 ``pi/180``), its
cosine and sine are taken in double and rounded to float32, the products and the difference are
float32 operations in that order (no fused multiply-add), and the rounding is half to even.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

_DEG2RAD = np.float32(math.pi / 180.0)


@njit(cache=True, nogil=True)
def orb_descriptors(img, cx, cy, angle, px, py, out):  # pragma: no cover - compiled
    """``out[k]`` = the descriptor of the keypoint at ``(cx[k], cy[k])`` (int64, pixels of the
    C-contiguous uint8 ``img``, already smoothed) with ``angle[k]`` (float32 degrees); ``px, py``
    are the float32 pattern points, pair ``q`` being points ``2q, 2q + 1``. Per keypoint the rotated,
    rounded offsets of all points are computed first (a loop the compiler vectorizes), then read
    pair by pair. The caller guarantees every rotated sample lies inside ``img`` (unchecked reads)."""
    f = img.reshape(-1)
    w = img.shape[1]
    w32 = np.int32(w)
    deg = np.float32(_DEG2RAD)
    nbytes = out.shape[1]
    m = px.shape[0]
    off = np.empty(m, np.int32)
    for k in range(cx.shape[0]):
        a = angle[k] * deg
        ca = np.float32(math.cos(np.float64(a)))
        sa = np.float32(math.sin(np.float64(a)))
        for i in range(m):
            u = np.int32(np.rint(px[i] * ca - py[i] * sa))
            v = np.int32(np.rint(px[i] * sa + py[i] * ca))
            off[i] = v * w32 + u
        c = cy[k] * w + cx[k]
        for i in range(nbytes):
            val = 0
            for j in range(8):
                q = 16 * i + 2 * j
                if f[np.uint64(c + off[q])] < f[np.uint64(c + off[q + 1])]:
                    val |= 1 << j
            out[k, i] = np.uint8(val)


def warm() -> None:
    """Call every kernel once on tiny inputs (so the first real call pays no load or compile)."""
    img = np.zeros((5, 5), np.uint8)
    px = np.zeros(16, np.float32)
    px[1::2] = 1.0
    out = np.zeros((1, 1), np.uint8)
    orb_descriptors(img, np.array([2], np.int64), np.array([2], np.int64), np.array([30.0], np.float32),
                    px, np.zeros(16, np.float32), out)
