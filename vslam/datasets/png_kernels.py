"""Compiled (numba) kernel of :mod:`vslam.datasets.png`: undoing the PNG row filters.

A PNG's inflated image data is, per row, one filter-type byte and the row's filtered bytes. Each
byte ``x`` was stored as ``Filt(x) = Orig(x) - Pred(x) mod 256`` with one of five predictors from
the reconstructed bytes ``a`` (left, ``bpp`` bytes back), ``b`` (above) and ``c`` (above-left),
taken as 0 outside the image (W3C PNG specification, 3rd edition, section 9.2 "Filter types for
filter method 0")::

    0 None     Pred = 0
    1 Sub      Pred = a
    2 Up       Pred = b
    3 Average  Pred = floor((a + b) / 2)
    4 Paeth    Pred = the one of a, b, c closest to p = a + b - c (ties: a, then b, then c)

Integer arithmetic only, so the result is the same bytes as any conforming decoder's (libpng's,
which OpenCV uses) on every machine. The rows are sequential (each needs the one above), and within
a row Sub, Average and Paeth are sequential in ``x`` (each needs ``a``).
"""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True, inline="always")
def _paeth(a, b, c):  # pragma: no cover - compiled
    """Of ``a``, ``b``, ``c``, the one closest to ``p = a + b - c`` (ties: ``a``, then ``b``)."""
    pa = abs(b - c)  # |p - a|
    pb = abs(a - c)  # |p - b|
    pc = abs(a + b - 2 * c)  # |p - c|
    if pa <= pb and pa <= pc:
        return a
    if pb <= pc:
        return b
    return c


@njit(cache=True, nogil=True)
def unfilter(raw, out, bpp):  # pragma: no cover - compiled
    """Reconstruct ``out`` (``(H, N)`` uint8, ``N`` bytes a row) from ``raw`` (``H * (N + 1)``
    uint8: each row's filter type, then its ``N`` filtered bytes), ``bpp`` bytes a pixel (at
    least 1). Returns False at a filter type above 4 (a corrupt file; ``out`` is then partial)."""
    h, n = out.shape
    stride = n + 1
    zero = np.zeros(n, np.uint8)
    for y in range(h):
        f = raw[y * stride]
        s = y * stride + 1
        cur = out[y]
        prev = out[y - 1] if y > 0 else zero
        if f == 0:
            for x in range(n):
                cur[x] = raw[s + x]
        elif f == 1:
            for x in range(min(bpp, n)):
                cur[x] = raw[s + x]
            for x in range(bpp, n):
                cur[x] = (np.int32(raw[s + x]) + np.int32(cur[x - bpp])) & 255
        elif f == 2:
            for x in range(n):
                cur[x] = (np.int32(raw[s + x]) + np.int32(prev[x])) & 255
        elif f == 3:
            for x in range(min(bpp, n)):
                cur[x] = (np.int32(raw[s + x]) + (np.int32(prev[x]) >> 1)) & 255
            for x in range(bpp, n):
                cur[x] = (np.int32(raw[s + x]) + ((np.int32(cur[x - bpp]) + np.int32(prev[x])) >> 1)) & 255
        elif f == 4 and bpp == 1:  # grey 8-bit, the common case: a and c carried in registers
            a = np.int32(0)
            c = np.int32(0)
            for x in range(n):
                b = np.int32(prev[x])
                a = (np.int32(raw[s + x]) + _paeth(a, b, c)) & 255
                cur[x] = a
                c = b
        elif f == 4:
            for x in range(min(bpp, n)):  # a = c = 0: the predictor is b
                cur[x] = (np.int32(raw[s + x]) + np.int32(prev[x])) & 255
            for x in range(bpp, n):
                pred = _paeth(np.int32(cur[x - bpp]), np.int32(prev[x]), np.int32(prev[x - bpp]))
                cur[x] = (np.int32(raw[s + x]) + pred) & 255
        else:
            return False
    return True


def warm() -> None:
    """Call the kernel once on a tiny input (so the first real call pays no load or compile)."""
    unfilter(np.zeros(2 * 3, np.uint8), np.zeros((2, 2), np.uint8), 1)
