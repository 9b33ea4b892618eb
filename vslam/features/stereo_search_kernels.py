"""Compiled (numba) kernel of :func:`vslam.features.stereo_search.match_rows`: coarse-to-fine
Lucas-Kanade along the rows of a rectified pair (the disparity is the only unknown).

Per point and pyramid level (coarsest first) the left window ``I`` (side ``W = 2w + 1``, its
columns at the keypoint's sub-pixel level position, linear interpolation along the row, its rows
the nearest level row) and its zero-mean row gradient ``g = dI/dx - mean`` are fixed; Gauss-Newton
on ``E(d) = sum_window (J(x - d) - I(x))^2`` (``J`` the right image at the same rows, interpolated
linearly along x) gives (Lucas & Kanade 1981; the gradient of the template as in Bouguet 2001)

    ``delta = sum((J(x - d) - I(x)) g) / sum(g^2)``,  ``d <- d + delta``.

``g`` is zero-mean, so a brightness offset between the cameras drops out of the numerator. With
the right window starting at ``k + a`` (``k`` integer, ``0 <= a < 1``) the numerator is
``(1 - a) T(k) + a T(k + 1) - sum(I g)`` with ``T(k) = sum g(r, c) J(r, k + c)``: one dot product
per integer start the iteration visits (cached), not a window interpolation per iteration.
"""
from __future__ import annotations

import numpy as np
from numba import njit


# reassociation lets LLVM vectorize the window sums (this kernel has no bit-identical NumPy twin);
# no NaN / inf assumptions, so the NaN check below stays
_FAST = {"reassoc", "contract"}


@njit(cache=True, nogil=True, fastmath=_FAST)
def _dot_at(img, start, stride, g, W):  # pragma: no cover - compiled
    """``sum_{r, c} g[r, c] * img[start + r * stride + c]`` (``img`` flat uint8, ``g`` (W, W) float32)."""
    s = np.float32(0.0)
    for r in range(W):
        o = start + r * stride
        row = img[o:o + W]  # a slice: the loop indices are non-negative, no wrap-around test
        gr = g[r]
        for c in range(W):
            s += gr[c] * np.float32(row[c])
    return np.float64(s)


@njit(cache=True, nogil=True, fastmath=_FAST)
def _template(img, start, stride, fx, W, g):  # pragma: no cover - compiled
    """The left window starting (sub-pixel) ``fx`` right of flat index ``start`` (row 0, column 0),
    interpolated linearly along the row: fills ``g`` (W, W) float32 with its zero-mean row
    gradient (central differences of the interpolated rows) and returns ``(sum g^2, sum I g)``."""
    bx = np.float32(fx)
    ax = np.float32(1.0) - bx
    half = np.float32(0.5)
    sg = np.float32(0.0)
    sgg = np.float32(0.0)
    sig = np.float32(0.0)
    si = np.float32(0.0)
    for r in range(W):
        o = start + r * stride - 1
        row = img[o:o + W + 3]
        gr = g[r]
        for c in range(W):
            a0 = np.float32(row[c])
            a1 = np.float32(row[c + 1])
            a2 = np.float32(row[c + 2])
            a3 = np.float32(row[c + 3])
            iv = ax * a1 + bx * a2
            gc = half * (ax * (a2 - a0) + bx * (a3 - a1))
            gr[c] = gc
            sg += gc
            sgg += gc * gc
            sig += iv * gc
            si += iv
    area = W * W
    mg = sg / np.float32(area)
    for r in range(W):
        gr = g[r]
        for c in range(W):
            gr[c] -= mg
    # sum (g - mg)^2 = sum g^2 - (sum g)^2 / area; sum I (g - mg) = sum I g - mg sum I
    return np.float64(sgg) - np.float64(sg) * np.float64(sg) / area, np.float64(sig) - np.float64(mg) * np.float64(si)


@njit(cache=True, nogil=True)
def row_lk(left, right, offs, widths, heights, pad, u, v, d0, w, max_iter, eps, min_grad2, disp, ok, last_step):  # pragma: no cover - compiled
    """Coarse-to-fine row Lucas-Kanade for every point ``(u[i], v[i])`` (level-0 pixels) from the
    initial disparity ``d0[i]`` (level-0 pixels).

    ``left`` / ``right``: flat uint8 pyramids, level ``L`` (``2^-L`` scale) starting at
    ``offs[L]`` with ``heights[L] + 2 pad`` rows of ``widths[L] + 2 pad`` columns (each level padded by
    ``pad`` pixels on every side). At a level the iteration stops after ``max_iter`` steps or once
    ``delta^2 <= eps`` (OpenCV's criterion), or halves its last step when it oscillates
    (``|delta + previous delta| < 0.01``, as OpenCV does); the disparity is doubled for the next level.

    Fills ``disp`` (level-0 pixels), ``ok`` (the window's mean squared zero-mean row gradient is at
    least ``min_grad2`` at every level, level 0 converged, all windows inside the padded images at
    level 0) and ``last_step`` (the last level-0 step, pixels).
    """
    W = 2 * w + 1
    area = W * W
    nlev = offs.shape[0]
    g = np.empty((W, W), np.float32)
    for i in range(u.shape[0]):
        d = d0[i] / (1 << (nlev - 1))
        good = True
        step = 0.0
        converged = False
        for lev in range(nlev - 1, -1, -1):
            if lev < nlev - 1:
                d *= 2.0
            scale = 1.0 / (1 << lev)
            wl = widths[lev]
            hl = heights[lev]
            stride = wl + 2 * pad
            base = offs[lev]
            xs = u[i] * scale - w  # left window start column (sub-pixel)
            iy = np.int64(np.floor(v[i] * scale + 0.5)) - w  # first window row
            ix = np.int64(np.floor(xs))
            # left columns ix - 1 .. ix + W + 1, rows iy .. iy + W - 1 must lie in the padded level
            if iy < -pad or iy + W > hl + pad or ix - 1 < -pad or ix + W + 2 > wl + pad:
                if lev == 0:
                    good = False
                continue
            rstart = base + (iy + pad) * stride + pad  # flat index of the window's first row, column 0
            hgg, sig = _template(left, rstart + ix, stride, xs - ix, W, g)
            if hgg < min_grad2 * area:
                good = False
                break
            kc = np.int64(-(1 << 40))  # integer start whose T(k), T(k + 1) are cached
            t0 = 0.0
            t1 = 0.0
            prev = 0.0
            converged = False
            for it in range(max_iter):
                xr = xs - d
                if not (xr == xr):  # NaN
                    good = False
                    break
                k = np.int64(np.floor(xr))
                if k < -pad or k + W + 1 > wl + pad:
                    if lev == 0:
                        good = False
                    break
                a = xr - k
                if k == kc + 1:
                    t0 = t1
                    t1 = _dot_at(right, rstart + k + 1, stride, g, W)
                elif k == kc - 1:
                    t1 = t0
                    t0 = _dot_at(right, rstart + k, stride, g, W)
                elif k != kc:
                    t0 = _dot_at(right, rstart + k, stride, g, W)
                    t1 = _dot_at(right, rstart + k + 1, stride, g, W)
                kc = k
                step = ((1.0 - a) * t0 + a * t1 - sig) / hgg
                if it > 0 and abs(step + prev) < 0.01:
                    d += 0.5 * step
                    converged = True
                    break
                d += step
                prev = step
                if step * step <= eps:
                    converged = True
                    break
            if not good:
                break
        disp[i] = d
        ok[i] = good and converged
        last_step[i] = step


def warm() -> None:
    """Call the kernel once on tiny inputs (so the first real call pays no load or compile)."""
    w, pad = 1, 3
    img = np.zeros((8 + 2 * pad) * (8 + 2 * pad), np.uint8)
    i64 = np.array([0], np.int64)
    one = np.array([8], np.int64)
    x = np.array([4.0])
    row_lk(img, img, i64, one, one, pad, x, x, np.zeros(1), w, 2, 0.01, 0.1, np.zeros(1), np.zeros(1, np.bool_),
           np.zeros(1))
