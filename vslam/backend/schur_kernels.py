"""Compiled (numba) per-observation kernels of :mod:`vslam.backend.schur_lm`.

:func:`predict` and the per-observation Gauss-Newton products of :func:`linearize` follow the NumPy
expressions they replaced in the same floating-point operation order (every product and ``einsum``
contraction written out term by term, point sums accumulated in observation order like
``np.bincount``). The camera sums are accumulated in the same loop (observation order per camera),
and the Schur complement is summed per point over its observation pairs
(:func:`reduced_camera_system`, :func:`back_substitute`) instead of dense ``6 n_c x 3 P`` coupling
GEMMs: the same system with its sums in another order (results equal to ~1e-15 relative, and
deterministic). numba does not contract ``a * b + c`` into fused multiply-adds unless ``fastmath``
is on, which these kernels never set. Equations: see :func:`schur_lm._linearize`. :func:`warm`
loads (or compiles) every kernel once.
"""
from __future__ import annotations

import numpy as np
from numba import njit

# ``(i, k)`` index arrays are small: the kernels unroll the 3 x 3 products by hand


# Isotropic share of the point damping: lambda (max(diag Hpp, 1e-9) + ISOTROPIC_SHARE tr(Hpp) / 3). A monocular
# point seen once (or with tiny parallax) has a near-null depth direction that diag(Hpp) alone would leave
# undamped. (numba reads module globals as compile-time constants.)
ISOTROPIC_SHARE = 0.01


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


@njit(cache=True, nogil=True, inline="always")
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


@njit(cache=True, nogil=True, inline="always")
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


@njit(cache=True, nogil=True, inline="always")
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


@njit(cache=True, nogil=True, inline="always")
def _camera_blocks(m, v, A, B, C, b0, b1, b2, x, y, z, cs, Hcp):  # pragma: no cover - compiled
    """Adds observation ``m``'s camera summands to row ``v`` of ``cs (n_c, 33)``: A (9),
    C = [X]_x A (9, into scratch ``C``), D = -C [X]_x (9), b (3), X x b (3); writes
    ``Hcp[m] = [B; [X]_x B]^T (3, 6)``."""
    for j in range(3):
        C[0, j] = y * A[2, j] - z * A[1, j]
        C[1, j] = z * A[0, j] - x * A[2, j]
        C[2, j] = x * A[1, j] - y * A[0, j]
    for i in range(3):
        for j in range(3):
            cs[v, 3 * i + j] += A[i, j]
            cs[v, 9 + 3 * i + j] += C[i, j]
        cs[v, 18 + 3 * i] += C[i, 2] * y - C[i, 1] * z
        cs[v, 19 + 3 * i] += C[i, 0] * z - C[i, 2] * x
        cs[v, 20 + 3 * i] += C[i, 1] * x - C[i, 0] * y
    cs[v, 27] += b0
    cs[v, 28] += b1
    cs[v, 29] += b2
    cs[v, 30] += y * b2 - z * b1
    cs[v, 31] += z * b0 - x * b2
    cs[v, 32] += x * b1 - y * b0
    for j in range(3):
        Hcp[m, j, 0] = B[0, j]
        Hcp[m, j, 1] = B[1, j]
        Hcp[m, j, 2] = B[2, j]
        Hcp[m, j, 3] = y * B[2, j] - z * B[1, j]
        Hcp[m, j, 4] = z * B[0, j] - x * B[2, j]
        Hcp[m, j, 5] = x * B[1, j] - y * B[0, j]


@njit(cache=True, nogil=True)
def linearize(R, cam, pt, X_cam, r, chi2, w_rows, use_huber, huber, baseline, disparity, any_disparity,
              fx, fy, obs_var, Hcp, cs, Hpp, gp):  # pragma: no cover - compiled
    """Per-observation Gauss-Newton blocks (see ``schur_lm._linearize``).

    Fills ``Hpp (3, 3, P)`` and ``gp (3, P)``, summed over each point's observations in observation
    order (as ``np.bincount``); for the observations of variable cameras (``obs_var[m] >= 0``) sums
    the camera summands into ``cs (n_c, 33)`` (zeroed here) and writes the transposed coupling
    blocks ``Hcp (M, 3, 6)`` (observation-major: one contiguous block per observation).
    """
    A = np.empty((3, 3))
    B = np.empty((3, 3))
    C = np.empty((3, 3))
    n_p = Hpp.shape[2]
    acc = np.zeros((n_p, 12))  # Hpp (9) and gp (3) of each point, summed in observation order
    cs[:, :] = 0.0
    for m in range(cam.shape[0]):
        c = cam[m]
        p = pt[m]
        ok, w0, w1, w2 = _weights(m, chi2, w_rows, use_huber, huber)
        b0, b1, b2, x, y, z = _normal_blocks(m, ok, w0, w1, w2, X_cam, r, baseline, disparity, any_disparity,
                                             fx, fy, A)
        _point_sums(R, c, p, A, b0, b1, b2, B, acc)
        v = obs_var[m]
        if v >= 0:
            _camera_blocks(m, v, A, B, C, b0, b1, b2, x, y, z, cs, Hcp)
    for p in range(n_p):
        for i in range(3):
            for j in range(3):
                Hpp[i, j, p] = acc[p, 3 * i + j]
            gp[i, p] = acc[p, 9 + i]


@njit(cache=True, nogil=True)
def point_terms(Hcp, V, gp, pt_obs, obs_var, q0, k, p, Y, bc):  # pragma: no cover - compiled
    """Point ``p``'s part of the reduced system's right-hand side and its scratch: for each of its
    ``k`` free observations ``a`` (``pt_obs[q0 + a]``), ``Y[a] = (W_a V_p)^T`` and
    ``bc -= W_a V_p gp_p`` (:func:`reduced_camera_system`; shared with the block-sparse
    :func:`vslam.backend.schur_sparse.reduced_camera_blocks`)."""
    g0, g1, g2 = gp[0, p], gp[1, p], gp[2, p]
    for a in range(k):
        m = pt_obs[q0 + a]
        r6 = 6 * obs_var[m]
        for l in range(3):  # Y[a, l, :] = sum_j V[j, l] W[:, j]
            v0, v1, v2 = V[0, l, p], V[1, l, p], V[2, l, p]
            for i in range(6):
                Y[a, l, i] = Hcp[m, 0, i] * v0 + Hcp[m, 1, i] * v1 + Hcp[m, 2, i] * v2
        for i in range(6):
            bc[r6 + i] -= Y[a, 0, i] * g0 + Y[a, 1, i] * g1 + Y[a, 2, i] * g2


@njit(cache=True, nogil=True)
def reduced_camera_system(Hcp, V, gp, gc, pt_ptr, pt_obs, obs_var, S, bc, Y):  # pragma: no cover - compiled
    """The point-eliminated camera system, summed per point over its observation pairs.

    ``S = -sum_p sum_{i, j in obs(p)} W_i V_p W_j^T`` (6 x 6 blocks at cameras ``(c_i, c_j)``) and
    ``bc = gc - sum_p sum_{i in obs(p)} W_i V_p gp_p`` (Triggs et al. 2000, Sec. 6.1), with the
    coupling blocks ``W_i = Hcp[i]^T`` (``Hcp (M, 3, 6)``) of the free observations
    ``pt_obs[pt_ptr[p]:pt_ptr[p + 1]]`` of point ``p`` and their variable camera ``obs_var``.
    ``V (3, 3, P)`` is symmetric, so each unordered pair is computed once, into the block above the
    diagonal; the blocks below are its transposes, copied at the end. ``Y (k_max, 3, 6)`` is scratch
    for ``(W_i V_p)^T``. ``S (6 n_c, 6 n_c)`` is overwritten; the camera blocks ``U`` are the caller's.
    """
    S[:, :] = 0.0
    for i in range(bc.shape[0]):
        bc[i] = gc[i]
    n_p = pt_ptr.shape[0] - 1
    for p in range(n_p):
        q0 = pt_ptr[p]
        k = pt_ptr[p + 1] - q0
        if k == 0:
            continue
        point_terms(Hcp, V, gp, pt_obs, obs_var, q0, k, p, Y, bc)
        for a in range(k):
            ra = 6 * obs_var[pt_obs[q0 + a]]
            for b in range(a, k):
                mb = pt_obs[q0 + b]
                rb = 6 * obs_var[mb]
                if ra < rb or b == a:  # the usual case (observations sorted by camera): upper block
                    # W_b's 18 entries loaded once per pair, not once per product (~10 % faster on the
                    # 7-Scenes global BA; each entry's terms, order and sum are unchanged)
                    h00, h01, h02, h03, h04, h05 = (Hcp[mb, 0, 0], Hcp[mb, 0, 1], Hcp[mb, 0, 2], Hcp[mb, 0, 3],
                                                    Hcp[mb, 0, 4], Hcp[mb, 0, 5])
                    h10, h11, h12, h13, h14, h15 = (Hcp[mb, 1, 0], Hcp[mb, 1, 1], Hcp[mb, 1, 2], Hcp[mb, 1, 3],
                                                    Hcp[mb, 1, 4], Hcp[mb, 1, 5])
                    h20, h21, h22, h23, h24, h25 = (Hcp[mb, 2, 0], Hcp[mb, 2, 1], Hcp[mb, 2, 2], Hcp[mb, 2, 3],
                                                    Hcp[mb, 2, 4], Hcp[mb, 2, 5])
                    for i in range(6):
                        y0 = Y[a, 0, i]
                        y1 = Y[a, 1, i]
                        y2 = Y[a, 2, i]
                        row = ra + i
                        S[row, rb] -= y0 * h00 + y1 * h10 + y2 * h20
                        S[row, rb + 1] -= y0 * h01 + y1 * h11 + y2 * h21
                        S[row, rb + 2] -= y0 * h02 + y1 * h12 + y2 * h22
                        S[row, rb + 3] -= y0 * h03 + y1 * h13 + y2 * h23
                        S[row, rb + 4] -= y0 * h04 + y1 * h14 + y2 * h24
                        S[row, rb + 5] -= y0 * h05 + y1 * h15 + y2 * h25
                else:  # the transposed block (and both halves when one camera sees the point twice)
                    for i in range(6):
                        for j in range(6):
                            s = Y[a, 0, i] * Hcp[mb, 0, j] + Y[a, 1, i] * Hcp[mb, 1, j] + Y[a, 2, i] * Hcp[mb, 2, j]
                            S[rb + j, ra + i] -= s
                            if ra == rb:
                                S[ra + i, rb + j] -= s
    n = S.shape[0]
    for r in range(0, n, 6):
        for c in range(r + 6, n, 6):
            for i in range(6):
                for j in range(6):
                    S[c + j, r + i] = S[r + i, c + j]


@njit(cache=True, nogil=True)
def back_substitute(Hcp, V, gp, dc, pt_ptr, pt_obs, obs_var, dp):  # pragma: no cover - compiled
    """Point steps ``dp_p = V_p (gp_p - sum_{i in obs(p)} W_i^T dc_{c_i})`` into ``dp (3, P)``
    (layout as in :func:`reduced_camera_system`; ``dc (6 n_c,)``)."""
    n_p = pt_ptr.shape[0] - 1
    for p in range(n_p):
        e0, e1, e2 = gp[0, p], gp[1, p], gp[2, p]
        for q in range(pt_ptr[p], pt_ptr[p + 1]):
            m = pt_obs[q]
            r6 = 6 * obs_var[m]
            s0 = 0.0
            s1 = 0.0
            s2 = 0.0
            for i in range(6):
                d = dc[r6 + i]
                s0 += Hcp[m, 0, i] * d
                s1 += Hcp[m, 1, i] * d
                s2 += Hcp[m, 2, i] * d
            e0 -= s0
            e1 -= s1
            e2 -= s2
        for i in range(3):
            dp[i, p] = V[i, 0, p] * e0 + V[i, 1, p] * e1 + V[i, 2, p] * e2


@njit(cache=True, nogil=True)
def group_by_point(free, pf, pt_ptr, out):  # pragma: no cover - compiled
    """``out = free[np.argsort(pf, kind="stable")]`` by a counting sort: the observations ``free`` of
    each point ``pf`` in their given order, point after point (``pt_ptr``: the point offsets)."""
    pos = pt_ptr[:-1].copy()
    for i in range(free.shape[0]):
        p = pf[i]
        out[pos[p]] = free[i]
        pos[p] += 1


@njit(cache=True, nogil=True)
def robust_terms(chi2, prev, use_prev, active, use_huber, huber, out):  # pragma: no cover - compiled
    """The cost terms of the ``active`` observations, compacted into ``out``; returns their number.

    A non-finite ``chi2`` counts ``1e6 + 10 prev`` (``prev`` 0 where not finite) when ``use_prev``,
    else 0; with ``use_huber`` a term is Huber's ``rho``: ``c`` for ``sqrt(c) <= k``, else
    ``2 k sqrt(c) - k^2`` (the NumPy expressions of ``schur_lm._robust_cost``, element by element).
    """
    n = 0
    for m in range(chi2.shape[0]):
        if not active[m]:
            continue
        c = chi2[m]
        if not np.isfinite(c):
            if use_prev:
                q = prev[m]
                c = 1e6 + 10.0 * (q if np.isfinite(q) else 0.0)
            else:
                c = 0.0
        if use_huber:
            k = huber[m]
            e = np.sqrt(c)
            if not e <= k:
                c = 2.0 * k * e - k * k
        out[n] = c
        n += 1
    return n


@njit(cache=True, nogil=True)
def damped_point_inverse(Hpp, lam, V):  # pragma: no cover - compiled
    """``V_p = (Hpp_p + lam diag(max(diag Hpp_p, 1e-9) + iso_p))^-1`` with ``iso_p = 0.01 tr(Hpp_p) / 3``
    for ``Hpp (3, 3, P)``, by the adjugate (the arithmetic of ``schur_lm._inv3``, term by term)."""
    for p in range(Hpp.shape[2]):
        iso = ISOTROPIC_SHARE * (Hpp[0, 0, p] + Hpp[1, 1, p] + Hpp[2, 2, p]) / 3.0
        h = Hpp[0, 0, p]
        a = h + lam * ((h if not h < 1e-9 else 1e-9) + iso)
        h = Hpp[1, 1, p]
        e = h + lam * ((h if not h < 1e-9 else 1e-9) + iso)
        h = Hpp[2, 2, p]
        i = h + lam * ((h if not h < 1e-9 else 1e-9) + iso)
        b, c = Hpp[0, 1, p], Hpp[0, 2, p]
        d, f = Hpp[1, 0, p], Hpp[1, 2, p]
        g, k = Hpp[2, 0, p], Hpp[2, 1, p]
        c00, c01, c02 = e * i - f * k, c * k - b * i, b * f - c * e
        c10, c11, c12 = f * g - d * i, a * i - c * g, c * d - a * f
        c20, c21, c22 = d * k - e * g, b * g - a * k, a * e - b * d
        det = a * c00 + b * c10 + c * c20
        V[0, 0, p], V[0, 1, p], V[0, 2, p] = c00 / det, c01 / det, c02 / det
        V[1, 0, p], V[1, 1, p], V[1, 2, p] = c10 / det, c11 / det, c12 / det
        V[2, 0, p], V[2, 1, p], V[2, 2, p] = c20 / det, c21 / det, c22 / det


@njit(cache=True, nogil=True)
def add_damped_camera_blocks(S, Hcc, lam):  # pragma: no cover - compiled
    """``S[6k:6k+6, 6k:6k+6] += Hcc_k + lam diag(max(diag Hcc_k, 1e-9))`` for the camera blocks
    ``Hcc (n_c, 6, 6)`` (the Marquardt-damped ``U`` of the reduced system, as the NumPy it replaced)."""
    for k in range(Hcc.shape[0]):
        add_damped_block(S[6 * k:6 * k + 6, 6 * k:6 * k + 6], Hcc[k], lam)


@njit(cache=True, nogil=True)
def add_damped_block(D, H, lam):  # pragma: no cover - compiled
    """``D += H + lam diag(max(diag H, 1e-9))`` for one ``6 x 6`` camera block (a view of the dense
    ``S`` here, a stored block of :mod:`vslam.backend.schur_sparse`)."""
    for i in range(6):
        for j in range(6):
            h = H[i, j]
            if i == j:
                h = h + lam * (h if not h < 1e-9 else 1e-9)
            D[i, j] += h


def warm() -> None:
    """Call every kernel once on a one-camera, one-point problem (loads or compiles them)."""
    R = np.eye(3)[None].copy()
    t = np.zeros((1, 3))
    X = np.array([[0.0, 0.0, 2.0]])
    i0 = np.zeros(1, np.int64)
    ones, zeros, no = np.ones(1), np.zeros(1), np.zeros(1, np.bool_)
    r, chi2, X_cam = np.empty((3, 1)), np.empty(1), np.empty((3, 1))
    predict(R, t, X, i0, i0, np.ones((3, 1)), zeros, no, no, False, ones, ones, True, 1.0, 1.0, 0.0, 0.0,
            1e-3, r, chi2, X_cam)
    Hcp, cs, Hpp, gp = np.empty((1, 3, 6)), np.empty((1, 33)), np.empty((3, 3, 1)), np.empty((3, 1))
    linearize(R, i0, i0, X_cam, r, chi2, np.ones((3, 1)), True, ones, zeros, no, False, 1.0, 1.0, i0, Hcp, cs,
              Hpp, gp)
    V = np.eye(3).reshape(3, 3, 1).copy()
    ptr = np.array([0, 1], np.int64)
    S, bc = np.empty((6, 6)), np.empty(6)
    reduced_camera_system(Hcp, V, gp, np.zeros(6), ptr, i0, i0, S, bc, np.empty((1, 3, 6)))
    back_substitute(Hcp, V, gp, np.zeros(6), ptr, i0, i0, np.empty((3, 1)))
    out = np.empty(1)
    group_by_point(i0, i0, ptr, out.astype(np.int64))
    robust_terms(chi2, chi2, True, np.ones(1, np.bool_), True, ones, out)
    damped_point_inverse(Hpp, 1e-4, np.empty((3, 3, 1)))
    add_damped_camera_blocks(S, np.ones((1, 6, 6)), 1e-4)
    # the kernels the others call (and schur_sparse's): loading a caller from the cache does not give
    # its callees machine code of their own, so they are called once here too
    point_terms(Hcp, V, gp, i0, i0, 0, 1, 0, np.empty((1, 3, 6)), bc)
    add_damped_block(S[:6, :6], np.ones((6, 6)), 1e-4)
