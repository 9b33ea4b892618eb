"""Compiled (numba) kernel of :func:`vslam.features.stereo.refine_disparity_row`: the row-constrained
(1-D) Lucas-Kanade disparity refinement, one point at a time in one loop: Gauss-Newton, with the
window sums of each window start it visits.

Every window sum is a plain float64 sum in a fixed order (no BLAS, no fused multiply-add: numba
never contracts ``a * b + c`` without ``fastmath``), so the result is the same on every CPU and
numba target. For 8-bit images the per-column sums of ``I_r``, ``g = dI_r/dx`` and their
products are integers, halves or quarters, exact in float64 in any order; ``sum I_l g`` over the zero-mean left window
is not exact, with a rounding error of at most ``n u sum|I_l g|`` for ``n = (2w+1)^2`` terms and
``u = 2^-53`` (Higham, "Accuracy and Stability of Numerical Algorithms", 2nd ed., eq. 4.4).
``tests/features/test_stereo_kernels.py`` compares the kernel against a NumPy oracle with
tolerances derived from that bound.

:func:`warm` loads (or compiles) the kernel once.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def _load(left, right, u, v, xs, w, pl, st, gr):  # pragma: no cover - compiled
    """The zero-mean left window ``pl (W, W)`` centred on ``(u, v)``, the right strip ``st (W, S)``
    from right column ``xs`` and its central difference ``gr = (I_r(x+1) - I_r(x-1)) / 2``."""
    W = pl.shape[0]
    S = st.shape[1]
    tot = 0.0
    for r in range(W):
        for c in range(W):
            p = float(left[v - w + r, u - w + c])
            pl[r, c] = p
            tot += p
    mean = tot / (W * W)
    for r in range(W):
        for c in range(W):
            pl[r, c] -= mean
        for s in range(S):
            x = xs + s
            st[r, s] = float(right[v - w + r, x])
            gr[r, s] = 0.5 * (float(right[v - w + r, x + 1]) - float(right[v - w + r, x - 1]))


@njit(cache=True, nogil=True)
def _column_sums(st, gr, s, col):  # pragma: no cover - compiled
    """``col[:, s]``: the seven right-image sums of :func:`_window` over the rows of strip column
    ``s`` (``I_r``, ``g``, ``I_r g``, ``g^2``, ``I_r g(+1)``, ``I_r(+1) g``, ``g g(+1)``; the ``(+1)``
    terms count 0 at the strip's last column)."""
    W, S = st.shape
    A = B = P00 = Q00 = P01 = P10 = Q01 = 0.0
    for r in range(W):
        i = st[r, s]
        g = gr[r, s]
        A += i
        B += g
        P00 += i * g
        Q00 += g * g
        if s + 1 < S:
            g1 = gr[r, s + 1]
            P01 += i * g1
            P10 += st[r, s + 1] * g
            Q01 += g * g1
    col[0, s] = A
    col[1, s] = B
    col[2, s] = P00
    col[3, s] = Q00
    col[4, s] = P01
    col[5, s] = P10
    col[6, s] = Q01


@njit(cache=True, nogil=True)
def _window(pl, st, gr, j, col, have_col, win, Ct):  # pragma: no cover - compiled
    """The sums of the right window starting at strip column ``j``: ``win[:, j] = (A, B, P00, Q00,
    P01, P10, Q01)`` with ``A = sum I_r(j)``, ``B = sum g(j)``, ``P00 = sum I_r(j) g(j)``,
    ``Q00 = sum g(j)^2``, ``P01 = sum I_r(j) g(j+1)``, ``P10 = sum I_r(j+1) g(j)``,
    ``Q01 = sum g(j) g(j+1)``, and ``Ct[j] = sum I_l g(j)``; every sum over the window's rows and
    columns. The seven right-image sums add up per-column sums (:func:`_column_sums`, each column
    once per point: ``have_col``). For 8-bit images their terms are integers, halves and quarters,
    exact in float64 in any order, so the result is the same bits as one loop over the window.
    ``Ct``, over the zero-mean left window (not exact), is summed in the window's row-major order."""
    W = pl.shape[0]
    for s in range(j, j + W):
        if not have_col[s]:
            _column_sums(st, gr, s, col)
            have_col[s] = True
    for q in range(7):
        t = 0.0
        for c in range(W):
            t += col[q, j + c]
        win[q, j] = t
    C = 0.0
    for r in range(W):
        for c in range(W):
            C += pl[r, c] * gr[r, j + c]
    Ct[j] = C


@njit(cache=True, nogil=True)
def _gauss_newton(pl, st, gr, col, have_col, win, Ct, have, base, d_init, iters, N):  # pragma: no cover - compiled
    """Gauss-Newton on the disparity from ``d_init``, the right window starting at strip column
    ``base - d``, each window sum interpolated linearly between integer starts
    (``a = pos - floor(pos)``: ``sum I_r g`` becomes ``b^2 P00(k) + ab (P01 + P10)(k) + a^2 P00(k+1)``).
    The sums of a start are computed when an iteration first needs them (:func:`_window`;
    ``have``): a few starts near ``d_init`` of the strip's ``S - W + 1``. Returns ``(d, good, last step)``."""
    last_start = win.shape[1] - 1
    d = d_init
    good = True
    step = 0.0
    for _ in range(iters):
        pos = base - d
        k = int(math.floor(pos))
        if k < 0 or k + 1 > last_start:
            good = False
        k = min(max(k, 0), last_start - 1)
        for j in (k, k + 1):
            if not have[j]:
                _window(pl, st, gr, j, col, have_col, win, Ct)
                have[j] = True
        a = pos - k
        b = 1.0 - a
        s_ig = b * b * win[2, k] + a * b * (win[4, k] + win[5, k]) + a * a * win[2, k + 1]
        s_gg = b * b * win[3, k] + 2.0 * a * b * win[6, k] + a * a * win[3, k + 1]
        s_i = b * win[0, k] + a * win[0, k + 1]
        s_g = b * win[1, k] + a * win[1, k + 1]
        s_lg = b * Ct[k] + a * Ct[k + 1]
        hgg = s_gg - s_g * s_g / N  # sum (g - mean g)^2
        if hgg <= 1e-6:  # no texture along the row
            good = False
            step = srg = 0.0
            continue
        # delta = sum(r g) / sum((g - mean g)^2), r = (I_r - mean) - I_l
        srg = s_ig - s_i * s_g / N - s_lg
        step = min(max(srg / hgg, -1.0), 1.0)
        d += step
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
    pl = np.empty((W, W))
    st = np.empty((W, S))
    gr = np.empty((W, S))
    col = np.empty((7, S))
    have_col = np.empty(S, np.bool_)
    win = np.empty((7, nS))
    Ct = np.empty(nS)
    have = np.empty(nS, np.bool_)
    for k in range(ul.shape[0]):
        _load(left, right, ul[k], vl[k], x0[k], w, pl, st, gr)
        have_col[:] = False
        have[:] = False
        d, good, step = _gauss_newton(pl, st, gr, col, have_col, win, Ct, have, float(ul[k] - w - x0[k]), d0[k],
                                      iters, N)
        good = good and abs(step) < tol and abs(d - d0[k]) <= max_change[k]
        disp[k] = d if good else d0[k]
        ok[k] = good


def warm() -> None:
    """Call the kernel once on tiny inputs (so the first real call pays no load or compile)."""
    img = np.zeros((8, 16), np.uint8)
    one = np.ones(1, np.int64)
    refine_rows(img, img, one * 3, one * 3, one * 2, np.ones(1), np.ones(1), 1, 5, 1, 0.25, np.zeros(1), np.zeros(1, np.bool_))
