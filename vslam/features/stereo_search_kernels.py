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
per integer start the iteration visits (cached), not a window interpolation per iteration. At
level 0 the zero-mean normalized cross-correlation of the two windows is the last check.
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
def _dot2_at(img, start, stride, g, W):  # pragma: no cover - compiled
    """``(_dot_at(img, start, ...), _dot_at(img, start + 1, ...))`` in one pass over the rows."""
    s0 = np.float32(0.0)
    s1 = np.float32(0.0)
    for r in range(W):
        o = start + r * stride
        row = img[o:o + W + 1]
        gr = g[r]
        for c in range(W):
            s0 += gr[c] * np.float32(row[c])
            s1 += gr[c] * np.float32(row[c + 1])
    return np.float64(s0), np.float64(s1)


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


@njit(cache=True, nogil=True, fastmath=_FAST)
def _zncc(left, lstart, fl, right, rstart, fr, stride, W):  # pragma: no cover - compiled
    """Zero-mean normalized cross-correlation of the two windows starting (sub-pixel) ``fl`` / ``fr``
    right of the flat indices ``lstart`` / ``rstart`` (rows ``stride`` apart, linear interpolation
    along the row); 0 where either window is flat."""
    bl = np.float32(fl)
    al = np.float32(1.0) - bl
    br = np.float32(fr)
    ar = np.float32(1.0) - br
    si = np.float32(0.0)
    sj = np.float32(0.0)
    sii = np.float32(0.0)
    sjj = np.float32(0.0)
    sij = np.float32(0.0)
    for r in range(W):
        lo = lstart + r * stride
        ro = rstart + r * stride
        lrow = left[lo:lo + W + 1]
        rrow = right[ro:ro + W + 1]
        for c in range(W):
            iv = al * np.float32(lrow[c]) + bl * np.float32(lrow[c + 1])
            jv = ar * np.float32(rrow[c]) + br * np.float32(rrow[c + 1])
            si += iv
            sj += jv
            sii += iv * iv
            sjj += jv * jv
            sij += iv * jv
    n = W * W
    vi = np.float64(sii) - np.float64(si) * np.float64(si) / n
    vj = np.float64(sjj) - np.float64(sj) * np.float64(sj) / n
    if vi <= 1e-9 or vj <= 1e-9:
        return 0.0
    return (np.float64(sij) - np.float64(si) * np.float64(sj) / n) / np.sqrt(vi * vj)


@njit(cache=True, nogil=True)
def _iterate(right, rstart, stride, g, W, xs, d, sig, hgg, k_min, k_max, max_iter, eps):  # pragma: no cover - compiled
    """Gauss-Newton steps of one level from the disparity ``d`` (module doc): the right window
    starts at ``xs - d`` (column ``k + a`` of the row starting at flat index ``rstart``), its
    integer start ``k`` must stay in ``[k_min, k_max]``. Returns ``(d, last step, status)``:
    0 converged (``step^2 <= eps``, or oscillating: half the last step taken, as OpenCV does),
    1 ``max_iter`` steps taken, 2 the window left the image, 3 NaN."""
    kc = np.int64(-(1 << 40))  # integer start whose T(k), T(k + 1) are cached
    t0 = 0.0
    t1 = 0.0
    prev = 0.0
    step = 0.0
    for it in range(max_iter):
        xr = xs - d
        if not (xr == xr):
            return d, step, 3
        k = np.int64(np.floor(xr))
        if k < k_min or k > k_max:
            return d, step, 2
        a = xr - k
        if k == kc + 1:
            t0 = t1
            t1 = _dot_at(right, rstart + k + 1, stride, g, W)
        elif k == kc - 1:
            t1 = t0
            t0 = _dot_at(right, rstart + k, stride, g, W)
        elif k != kc:
            t0, t1 = _dot2_at(right, rstart + k, stride, g, W)
        kc = k
        step = ((1.0 - a) * t0 + a * t1 - sig) / hgg
        if it > 0 and abs(step + prev) < 0.01:
            return d + 0.5 * step, step, 0
        d += step
        prev = step
        if step * step <= eps:
            return d, step, 0
    return d, step, 1


@njit(cache=True, nogil=True)
def row_lk(left, right, offs, widths, heights, pad, u, v, d0, w, max_iter, eps, min_grad2, min_zncc, disp, ok,
           zncc):  # pragma: no cover - compiled
    """Coarse-to-fine row Lucas-Kanade for every point ``(u[i], v[i])`` (level-0 pixels) from the
    initial disparity ``d0[i]`` (level-0 pixels).

    ``left`` / ``right``: flat uint8 pyramids, level ``L`` (``2^-L`` scale) starting at
    ``offs[L]`` with ``heights[L] + 2 pad`` rows of ``widths[L] + 2 pad`` columns (each level padded by
    ``pad`` pixels on every side). At a level the iteration stops after ``max_iter`` steps or once
    ``delta^2 <= eps`` (OpenCV's criterion), or halves its last step when it oscillates
    (``|delta + previous delta| < 0.01``, as OpenCV does); the disparity is doubled for the next level.

    Fills ``disp`` (level-0 pixels), ``zncc`` (the level-0 windows' zero-mean normalized
    cross-correlation at ``disp``; 0 where not reached) and ``ok``: the window's mean squared
    zero-mean row gradient is at least ``min_grad2`` at every level, level 0 converged with all
    windows inside the padded images, and ``zncc >= min_zncc`` (a wrong local minimum of the SSD
    correlates poorly).
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
            d, step, status = _iterate(right, rstart, stride, g, W, xs, d, sig, hgg, -pad, wl + pad - W - 1, max_iter,
                                       eps)
            converged = status == 0
            if status == 3 or (status == 2 and lev == 0):  # NaN, or the level-0 window left the image
                good = False
            if not good:
                break
        disp[i] = d
        zn = 0.0
        if good and converged:
            # the level-0 window (its row, start and stride as in the loop above at lev == 0)
            stride = widths[0] + 2 * pad
            xs = u[i] - w
            iy = np.int64(np.floor(v[i] + 0.5)) - w
            ix = np.int64(np.floor(xs))
            xr = xs - d
            k = np.int64(np.floor(xr))
            if k >= -pad and k + W + 1 <= widths[0] + pad:
                rstart = offs[0] + (iy + pad) * stride + pad
                zn = _zncc(left, rstart + ix, xs - ix, right, rstart + k, xr - k, stride, W)
            else:
                good = False
        zncc[i] = zn
        ok[i] = good and converged and zn >= min_zncc


def warm() -> None:
    """Call the kernel once on tiny inputs (so the first real call pays no load or compile)."""
    w, pad = 1, 3
    img = np.zeros((8 + 2 * pad) * (8 + 2 * pad), np.uint8)
    i64 = np.array([0], np.int64)
    one = np.array([8], np.int64)
    x = np.array([4.0])
    row_lk(img, img, i64, one, one, pad, x, x, np.zeros(1), w, 2, 0.01, 0.1, 0.5, np.zeros(1), np.zeros(1, np.bool_),
           np.zeros(1))
