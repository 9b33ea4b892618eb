"""Compiled (numba) kernel of :func:`vslam.features.stereo.refine_disparity_row`: the row-constrained
(1-D) Lucas-Kanade disparity refinement, one point at a time in one loop (window sums, then
Gauss-Newton), instead of NumPy tables built for all points at once.

It computes what the tabulated NumPy version (kept in ``tests/features/test_stereo_kernels.py`` as
the oracle) computed, bit for bit on 8-bit images:

* the per-column sums of ``I_r``, ``g = dI_r/dx`` and their products over the window rows are exact
  in float32 for 8-bit images (integers and halves below ``2^24``), so their order does not matter,
  and their running window sums are exact in float64;
* the left window mean is the exact sum of 121 integers (as NumPy's float32 sum) divided by 121 in
  float32;
* ``sum I_l g`` (zero-mean left window, not exact) is accumulated in float32 as OpenBLAS's sgemm of
  ``I_l^T g`` did, one fused multiply-add per window row in row order (LLVM's ``fma`` intrinsic, so
  the result does not depend on the compiler contracting, which numba never does without
  ``fastmath``), then the diagonal of those column pairs summed in column order in float32;
* the Gauss-Newton step repeats the NumPy expressions' float64 operation order term by term.

:func:`warm` loads (or compiles) the kernel once.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit, types
from numba.extending import intrinsic


@intrinsic
def _fma32(typingctx, a, b, c):
    """``a * b + c`` rounded once (float32), as a BLAS kernel's FMA computes it."""
    sig = types.float32(types.float32, types.float32, types.float32)

    def codegen(context, builder, signature, args):
        return builder.fma(*args)

    return sig, codegen


@njit(cache=True, nogil=True)
def _load(left, right, u, v, xs, w, pl, st, gr, ext):  # pragma: no cover - compiled
    """The zero-mean left window ``pl (W, W)`` centred on ``(u, v)``, the right strip ``st (W, S)``
    from right column ``xs`` and its central difference ``gr`` (all float32, as the NumPy tables);
    ``ext (S + 2,)`` is scratch."""
    W = pl.shape[0]
    S = st.shape[1]
    f32 = np.float32
    tot = 0.0  # exact for 8-bit images (integers), so equal to NumPy's float32 pairwise sum
    for r in range(W):
        row = left[v - w + r, u - w:u + w + 1]
        for c in range(W):
            p = f32(row[c])
            pl[r, c] = p
            tot += float(p)
    mean = f32(tot) / f32(W * W)
    for r in range(W):
        for c in range(W):
            pl[r, c] = pl[r, c] - mean
    for r in range(W):
        row = right[v - w + r, xs - 1:xs + S + 1]
        for s in range(S + 2):
            ext[s] = f32(row[s])
        for s in range(S):
            st[r, s] = ext[s + 1]
            gr[r, s] = f32(0.5) * (ext[s + 2] - ext[s])


@njit(cache=True, nogil=True)
def _window_sums(pl, st, gr, col, crs, win, Ct):  # pragma: no cover - compiled
    """For every integer start ``j`` of the right window in the strip (``0 <= j <= S - W``):
    ``win = (A, B, P00, Q00, P01, P10, Q01)``: ``A = sum I_r``, ``B = sum g``,
    ``P00 = sum I_r(j) g(j)``, ``Q00 = sum g(j)^2``, ``P01 = sum I_r(j) g(j+1)``,
    ``P10 = sum I_r(j+1) g(j)``, ``Q01 = sum g(j) g(j+1)`` (float64), and ``Ct = sum I_l g(j)``.
    ``col`` and ``crs`` are scratch."""
    W, S = st.shape
    nS = S - W + 1
    f32 = np.float32
    # per-column sums over the window rows (the shifted products padded with 0), seven running
    # sums side by side per column
    for s in range(S):
        a0 = f32(0.0)
        a1 = f32(0.0)
        a2 = f32(0.0)
        a3 = f32(0.0)
        a4 = f32(0.0)
        a5 = f32(0.0)
        a6 = f32(0.0)
        if s < S - 1:
            for r in range(W):
                i = st[r, s]
                g = gr[r, s]
                i1 = st[r, s + 1]
                g1 = gr[r, s + 1]
                a0 = a0 + i
                a1 = a1 + g
                a2 = _fma32(i, g, a2)
                a3 = _fma32(g, g, a3)
                a4 = _fma32(i, g1, a4)
                a5 = _fma32(i1, g, a5)
                a6 = _fma32(g, g1, a6)
        else:
            for r in range(W):
                i = st[r, s]
                g = gr[r, s]
                a0 = a0 + i
                a1 = a1 + g
                a2 = _fma32(i, g, a2)
                a3 = _fma32(g, g, a3)
        col[0, s] = a0
        col[1, s] = a1
        col[2, s] = a2
        col[3, s] = a3
        col[4, s] = a4
        col[5, s] = a5
        col[6, s] = a6
    # running window sums (float64; exact for 8-bit images)
    for t in range(7):
        acc = 0.0
        for s in range(W):
            acc += float(col[t, s])
        win[t, 0] = acc
        for j in range(1, nS):
            win[t, j] = (win[t, j - 1] + float(col[t, j + W - 1])) - float(col[t, j - 1])
    # sum I_l g(j): column pairs (c, j + c) summed over the rows (FMA, row order), then over c
    crs[:, :] = f32(0.0)
    for r in range(W):
        for c in range(W):
            p = pl[r, c]
            for j in range(nS):
                crs[c, j] = _fma32(p, gr[r, j + c], crs[c, j])
    for j in range(nS):
        acc32 = crs[0, j]
        for c in range(1, W):
            acc32 = acc32 + crs[c, j]
        Ct[j] = float(acc32)


@njit(cache=True, nogil=True)
def _gauss_newton(win, Ct, base, d_init, iters, N):  # pragma: no cover - compiled
    """Gauss-Newton on the disparity from ``d_init``, the right window starting at strip column
    ``base - d``, each window sum interpolated linearly between integer starts. Returns
    ``(d, good, last step)``; the float64 expressions are those of the NumPy version, in order."""
    last_start = win.shape[1] - 1
    d = d_init
    good = True
    step = 0.0
    for _ in range(iters):
        pos = base - d
        k = int(math.floor(pos))
        if k < 0 or k + 1 > last_start:
            good = False
        if k < 0:
            k = 0
        elif k > last_start - 1:
            k = last_start - 1
        a = pos - k
        b = 1.0 - a
        s_ig = b * b * win[2, k] + a * b * (win[4, k] + win[5, k]) + a * a * win[2, k + 1]
        s_gg = b * b * win[3, k] + 2.0 * a * b * win[6, k] + a * a * win[3, k + 1]
        s_i = b * win[0, k] + a * win[0, k + 1]
        s_g = b * win[1, k] + a * win[1, k + 1]
        s_lg = b * Ct[k] + a * Ct[k + 1]
        hgg = s_gg - s_g * s_g / N  # sum (g - mean g)^2
        flat = hgg <= 1e-6
        if flat:
            good = False
        # delta = sum(r g) / sum((g - mean g)^2), r = (I_r - mean) - I_l
        srg = s_ig - s_i * s_g / N - s_lg
        step = srg / (1.0 if flat else hgg)
        step = min(max(step, -1.0), 1.0)
        d += 0.0 if flat else step
    return d, good, step


@njit(cache=True, nogil=True)
def refine_rows(left, right, ul, vl, x0, d0, max_change, w, S, iters, tol, disp, ok):  # pragma: no cover - compiled
    """Refine the disparities of the points ``k`` (all in the image, strip inside the right image):
    left window ``(2w+1)^2`` centred on ``(ul[k], vl[k])``, right strip of ``S`` columns from right
    column ``x0[k]``, start ``d0[k]``. Writes ``disp[k]`` (``d0[k]`` where not converged) and ``ok[k]``
    (converged: last step under ``tol``, within ``max_change[k]`` of the start, window in the strip,
    texture along the row)."""
    W = 2 * w + 1
    nS = S - W + 1
    N = float(W * W)
    pl = np.empty((W, W), np.float32)
    st = np.empty((W, S), np.float32)
    gr = np.empty((W, S), np.float32)
    col = np.empty((7, S), np.float32)
    crs = np.empty((W, nS), np.float32)
    win = np.empty((7, nS), np.float64)
    Ct = np.empty(nS, np.float64)
    ext = np.empty(S + 2, np.float32)
    for k in range(ul.shape[0]):
        _load(left, right, ul[k], vl[k], x0[k], w, pl, st, gr, ext)
        _window_sums(pl, st, gr, col, crs, win, Ct)
        d, good, step = _gauss_newton(win, Ct, float(ul[k] - w - x0[k]), d0[k], iters, N)
        good = good and abs(step) < tol and abs(d - d0[k]) <= max_change[k]
        disp[k] = d if good else d0[k]
        ok[k] = good


def warm() -> None:
    """Call the kernel once on tiny inputs (so the first real call pays no load or compile)."""
    img = np.zeros((8, 16), np.uint8)
    one = np.ones(1, np.int64)
    refine_rows(img, img, one * 3, one * 3, one * 2, np.ones(1), np.ones(1), 1, 5, 1, 0.25, np.zeros(1), np.zeros(1, np.bool_))
