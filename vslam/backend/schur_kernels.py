"""Compiled (numba) per-observation kernels of :mod:`vslam.backend.schur_lm`.

They compute exactly what the NumPy expressions they replace computed, in the same floating-point
operation order (every product, sum and ``einsum`` contraction written out term by term, sums over
observations accumulated in observation order like ``np.bincount``), so the solver's results are
bit-identical with and without them; only the temporaries and the passes over memory are gone
(one loop over the observations instead of ~60 array expressions, and the coupling ``W`` and
``W blockdiag(V)`` written straight into their dense buffers instead of a dense ``einsum`` over
mostly-zero columns). numba does not contract ``a * b + c`` into fused multiply-adds unless
``fastmath`` is on, which these kernels never set. Equations: see :func:`schur_lm._linearize`.
"""
from __future__ import annotations

import numpy as np
from numba import njit

# ``(i, k)`` index arrays are small: the kernels unroll the 3 x 3 products by hand


@njit(cache=True, nogil=True)
def predict(R, t, X, cam, pt, meas_T, baseline, stereo, disparity, any_disparity, info, info_d, uniform,
            fx, fy, cx, cy, min_depth, r, chi2, X_cam):  # pragma: no cover - compiled
    """Fill ``r (3, M)``, ``chi2 (M,)`` and ``X_cam (3, M)`` (see ``schur_lm._predict``)."""
    m_all = cam.shape[0]
    for m in range(m_all):
        c = cam[m]
        p = pt[m]
        X0, X1, X2 = X[p, 0], X[p, 1], X[p, 2]
        x = 0.0 + R[c, 0, 0] * X0
        x = x + R[c, 0, 1] * X1
        x = x + R[c, 0, 2] * X2
        y = 0.0 + R[c, 1, 0] * X0
        y = y + R[c, 1, 1] * X1
        y = y + R[c, 1, 2] * X2
        z = 0.0 + R[c, 2, 0] * X0
        z = z + R[c, 2, 1] * X1
        z = z + R[c, 2, 2] * X2
        x = x + t[c, 0]
        y = y + t[c, 1]
        z = z + t[c, 2]
        X_cam[0, m] = x
        X_cam[1, m] = y
        X_cam[2, m] = z
        ok = z > min_depth
        inv_z = 1.0 / (z if ok else 1.0)
        u = fx * x * inv_z + cx
        r0 = meas_T[0, m] - u
        r1 = meas_T[1, m] - (fy * y * inv_z + cy)
        disp = fx * baseline[m] * inv_z
        r2 = meas_T[2, m] - (u - disp)
        if any_disparity and disparity[m]:
            r2 = (meas_T[0, m] - meas_T[2, m]) - disp
        if not stereo[m]:
            r2 = 0.0
        r[0, m] = r0
        r[1, m] = r1
        r[2, m] = r2
        if not ok:
            chi2[m] = np.inf
        elif uniform:
            s = 0.0 + r0 * r0
            s = s + r1 * r1
            s = s + r2 * r2
            chi2[m] = info[m] * s
        else:
            chi2[m] = info[m] * (r0 * r0 + r1 * r1) + info_d[m] * (r2 * r2)


@njit(cache=True, nogil=True)
def _weights(m, chi2, w_rows, use_huber, huber):  # pragma: no cover - compiled
    """Row weights of observation ``m`` (information x Huber IRLS weight; 0 where ``chi2`` is inf)
    and whether it is finite."""
    ok = np.isfinite(chi2[m])
    okf = 1.0 if ok else 0.0
    w0 = w_rows[0, m] * okf
    w1 = w_rows[1, m] * okf
    w2 = w_rows[2, m] * okf
    if use_huber:
        e = np.sqrt(chi2[m] if ok else 0.0)
        h = huber[m]
        if e <= h:
            f = 1.0
        else:
            f = h / (e if (e >= 1e-12 or e != e) else 1e-12)
        w0 = w0 * f
        w1 = w1 * f
        w2 = w2 * f
    return ok, w0, w1, w2


@njit(cache=True, nogil=True)
def _normal_blocks(m, ok, w0, w1, w2, X_cam, r, baseline, disparity, any_disparity, fx, fy, A):  # pragma: no cover - compiled
    """``A = Jh^T W Jh`` into ``A (3, 3)``; returns ``b = Jh^T W r`` and ``X_cam`` of observation ``m``."""
    x = X_cam[0, m]
    y = X_cam[1, m]
    z = X_cam[2, m]
    inv_z = 1.0 / (z if ok else 1.0)
    ja = fx * inv_z
    jb = fy * inv_z
    c0 = -ja * x * inv_z
    c1 = -jb * y * inv_z
    if any_disparity and disparity[m]:
        k2 = 0.0
        c2 = -ja * baseline[m] * inv_z
    else:
        k2 = ja
        c2 = -ja * (x - baseline[m]) * inv_z
    w0c0 = w0 * c0
    w1c1 = w1 * c1
    w2c2 = w2 * c2
    A[0, 0] = ja * ja * w0 + k2 * k2 * w2
    A[0, 1] = 0.0
    A[1, 0] = 0.0
    a02 = ja * w0c0 + k2 * w2c2
    A[0, 2] = a02
    A[2, 0] = a02
    A[1, 1] = jb * jb * w1
    a12 = jb * w1c1
    A[1, 2] = a12
    A[2, 1] = a12
    A[2, 2] = w0c0 * c0 + w1c1 * c1 + w2c2 * c2
    r0 = r[0, m]
    r1 = r[1, m]
    r2 = r[2, m]
    b0 = ja * w0 * r0 + k2 * w2 * r2
    b1 = jb * w1 * r1
    b2 = w0c0 * r0 + w1c1 * r1 + w2c2 * r2
    return b0, b1, b2, x, y, z


@njit(cache=True, nogil=True)
def _point_sums(R, c, p, A, b0, b1, b2, B, acc):  # pragma: no cover - compiled
    """``B = A R``; ``acc[p]`` += ``R^T B`` (9) and ``R^T b`` (3), in the einsum's order."""
    # B = A R (einsum "ilm,ljm->ijm": zero-initialized, summed over l in order)
    for i in range(3):
        for j in range(3):
            s = 0.0 + A[i, 0] * R[c, 0, j]
            s = s + A[i, 1] * R[c, 1, j]
            B[i, j] = s + A[i, 2] * R[c, 2, j]
    # Hpp += R^T B, gp += R^T b (einsum "lim,ljm->ijm" / "lim,lm->im", then bincount)
    for i in range(3):  # point-major accumulators (one cache line per point); transposed at the end
        for j in range(3):
            s = 0.0 + R[c, 0, i] * B[0, j]
            s = s + R[c, 1, i] * B[1, j]
            acc[p, 3 * i + j] += s + R[c, 2, i] * B[2, j]
        s = 0.0 + R[c, 0, i] * b0
        s = s + R[c, 1, i] * b1
        acc[p, 9 + i] += s + R[c, 2, i] * b2


@njit(cache=True, nogil=True)
def _camera_rows(m, A, B, b0, b1, b2, x, y, z, rows, H):  # pragma: no cover - compiled
    """Column ``m`` of ``rows (33, M)``: A (9), C = [X]_x A (9), D = -C [X]_x (9), b (3), X x b (3);
    and ``H = Hcp = [B; [X]_x B] (6, 3)``."""
    for i in range(3):
        for j in range(3):
            rows[3 * i + j, m] = A[i, j]
    for j in range(3):
        rows[9 + j, m] = y * A[2, j] - z * A[1, j]
        rows[12 + j, m] = z * A[0, j] - x * A[2, j]
        rows[15 + j, m] = x * A[1, j] - y * A[0, j]
    for i in range(3):
        Ci0 = rows[9 + 3 * i, m]
        Ci1 = rows[10 + 3 * i, m]
        Ci2 = rows[11 + 3 * i, m]
        rows[18 + 3 * i, m] = Ci2 * y - Ci1 * z
        rows[19 + 3 * i, m] = Ci0 * z - Ci2 * x
        rows[20 + 3 * i, m] = Ci1 * x - Ci0 * y
    rows[27, m] = b0
    rows[28, m] = b1
    rows[29, m] = b2
    rows[30, m] = y * b2 - z * b1
    rows[31, m] = z * b0 - x * b2
    rows[32, m] = x * b1 - y * b0
    for j in range(3):
        H[0, j] = B[0, j]
        H[1, j] = B[1, j]
        H[2, j] = B[2, j]
        H[3, j] = y * B[2, j] - z * B[1, j]
        H[4, j] = z * B[0, j] - x * B[2, j]
        H[5, j] = x * B[1, j] - y * B[0, j]


@njit(cache=True, nogil=True)
def linearize(R, cam, pt, X_cam, r, chi2, w_rows, use_huber, huber, baseline, disparity, any_disparity,
              fx, fy, with_cams, cam_row, n_p, dense, buf, Hcp, rows, Hpp, gp):  # pragma: no cover - compiled
    """Per-observation Gauss-Newton blocks (see ``schur_lm._linearize``).

    Fills ``Hpp (3, 3, P)`` and ``gp (3, P)``, summed over each point's observations in observation
    order (as ``np.bincount``);
    when ``with_cams`` fills ``rows (33, M)`` (the per-camera summands) and writes ``Hcp`` either
    into the dense coupling buffer ``buf`` (row ``6 cam_row + a``, column ``j P + p``) or into
    ``Hcp (6, 3, M)``.
    """
    A = np.empty((3, 3))
    B = np.empty((3, 3))
    H = np.empty((6, 3))
    acc = np.zeros((n_p, 12))  # Hpp (9) and gp (3) of each point, summed in observation order
    for m in range(cam.shape[0]):
        c = cam[m]
        p = pt[m]
        ok, w0, w1, w2 = _weights(m, chi2, w_rows, use_huber, huber)
        b0, b1, b2, x, y, z = _normal_blocks(m, ok, w0, w1, w2, X_cam, r, baseline, disparity, any_disparity,
                                             fx, fy, A)
        _point_sums(R, c, p, A, b0, b1, b2, B, acc)
        if not with_cams:
            continue
        _camera_rows(m, A, B, b0, b1, b2, x, y, z, rows, H)
        if dense:
            r6 = 6 * cam_row[m]
            for a in range(6):
                for j in range(3):
                    buf[r6 + a, j * n_p + p] = H[a, j]
        else:
            for a in range(6):
                for j in range(3):
                    Hcp[a, j, m] = H[a, j]
    for p in range(n_p):
        for i in range(3):
            for j in range(3):
                Hpp[i, j, p] = acc[p, 3 * i + j]
            gp[i, p] = acc[p, 9 + i]


@njit(cache=True, nogil=True)
def times_blockdiag(W, V, free, cam_row, pt, n_p, Y):  # pragma: no cover - compiled
    """``Y = W blockdiag(V)`` on the dense layout, only at the observed ``(camera, point)`` blocks
    (elsewhere ``W`` and so ``Y`` are zero; ``Y`` keeps its zeros between calls). Same sums as the
    dense ``einsum("ajp,jkp->akp")``: zero-initialized, over ``j`` in order."""
    for q in range(free.shape[0]):
        m = free[q]
        p = pt[m]
        r6 = 6 * cam_row[m]
        for a in range(6):
            w0 = W[r6 + a, p]
            w1 = W[r6 + a, n_p + p]
            w2 = W[r6 + a, 2 * n_p + p]
            for k in range(3):
                s = 0.0 + w0 * V[0, k, p]
                s = s + w1 * V[1, k, p]
                Y[r6 + a, k * n_p + p] = s + w2 * V[2, k, p]


def warm() -> None:
    """Call each kernel once on a tiny problem with the argument types :mod:`schur_lm` passes, so the
    first real call pays no loading (or compiling) of the cached machine code (~0.15 s)."""
    n_c, n_p = 2, 2
    cam = np.array([0, 0, 1], np.int64)
    pt = np.array([0, 1, 1], np.int64)
    m = len(cam)
    R = np.ascontiguousarray(np.tile(np.eye(3), (n_c, 1, 1)))
    t = np.zeros((n_c, 3))
    X = np.array([[0.0, 0.0, 2.0], [0.5, -0.5, 3.0]])
    meas_T = np.ascontiguousarray(np.array([[320.0, 240.0, 300.0]] * m).T)
    baseline = np.full(m, 0.1)
    stereo = np.ones(m, bool)
    disparity = np.zeros(m, bool)
    info = np.ones(m)
    r, chi2, X_cam = np.empty((3, m)), np.empty(m), np.empty((3, m))
    predict(R, t, X, cam, pt, meas_T, baseline, stereo, disparity, False, info, info, True,
            500.0, 500.0, 320.0, 240.0, 1e-3, r, chi2, X_cam)
    w_rows = np.ones((3, m))
    cam_row = np.array([0, 0, 1], np.int64)
    buf = np.zeros((6 * (n_c + 1), 3 * n_p))
    Hpp, gp = np.empty((3, 3, n_p)), np.empty((3, n_p))
    linearize(R, cam, pt, X_cam, r, chi2, w_rows, True, np.full(m, 5.0), baseline, disparity, False,
              500.0, 500.0, True, cam_row, n_p, True, buf, np.empty((6, 3, 0)), np.empty((33, m)), Hpp, gp)
    V = np.ascontiguousarray(np.tile(np.eye(3)[:, :, None], (1, 1, n_p)))
    times_blockdiag(buf[: 6 * n_c], V, np.arange(m), cam_row, pt, n_p, np.zeros((6 * n_c, 3 * n_p)))
