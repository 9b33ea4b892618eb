"""Compiled (numba) per-point kernels of :func:`vslam.geometry.pnp.refine_pose`, of the
inlier selection of :func:`vslam.geometry.pnp.solve_pnp` and of its Levenberg-Marquardt refinement
(:func:`lm_reprojection`, whose iterations are :func:`reproj_normal_equations`).

:func:`linearize` and :func:`inliers` compute exactly what ``_PoseResiduals.linearize`` /
``_PoseResiduals.inliers`` computed with NumPy, from the same camera points ``Xc = R X + t`` (still
NumPy's matrix product), in the same floating-point operation order term by term (``np.maximum`` /
``np.where`` NaN semantics included), so the pose optimization stays bit-identical; only the ~40
array temporaries per Gauss-Newton iteration are gone. numba does not contract ``a * b + c`` into
fused multiply-adds unless ``fastmath`` is on, which these kernels never set; ``error_model="numpy"``:
a division by zero gives inf/NaN as in NumPy.
Equations: ORB-SLAM2's pose optimization (Mur-Artal & Tardos 2017, eq. (2)-(3)), see ``refine_pose``.
"""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True, error_model="numpy")
def _nanmax(a, b):  # pragma: no cover - compiled
    """``np.maximum(a, b)`` for a scalar ``b``: NaN propagates."""
    return a if (a >= b or a != a) else b


@njit(cache=True, nogil=True, error_model="numpy")
def linearize(Xc, u_obs, v_obs, ur, has_r, info, delta, inl, fx, fy, cx, cy, bf, any_r, A, r):  # pragma: no cover
    """Fill the Huber-weighted Jacobian ``A (6, m n)`` and residuals ``r (m n,)`` (rows
    ``u_1..u_n, v_1..v_n[, ur_1..ur_n]``) from the camera points ``Xc (3, n)``."""
    n = u_obs.shape[0]
    for i in range(n):
        x = Xc[0, i]
        y = Xc[1, i]
        zc = Xc[2, i]
        z = _nanmax(zc, 1e-6)
        iz = 1.0 / z
        u_hat = fx * x * iz + cx
        v_hat = fy * y * iz + cy
        ru = u_hat - u_obs[i]
        rv = v_hat - v_obs[i]
        rs = ((u_hat - bf * iz) - ur[i]) if has_r[i] else 0.0
        e = np.sqrt(info[i] * (ru * ru + rv * rv + rs * rs))
        w = info[i] * (1.0 if e <= delta[i] else delta[i] / _nanmax(e, 1e-12))
        if not (inl[i] and zc > 0):
            w = 0.0
        sw = np.sqrt(w)
        a = fx * iz * sw
        c = fy * iz * sw
        b = -fx * x * iz * iz * sw
        d = -fy * y * iz * iz * sw
        A[0, i] = a
        A[1, i] = 0.0
        A[2, i] = b
        A[3, i] = b * y
        A[4, i] = a * z - b * x
        A[5, i] = -a * y
        j = n + i
        A[0, j] = 0.0
        A[1, j] = c
        A[2, j] = d
        A[3, j] = d * y - c * z
        A[4, j] = -d * x
        A[5, j] = c * x
        r[i] = ru * sw
        r[j] = rv * sw
        if any_r:
            swr = sw * (1.0 if has_r[i] else 0.0)
            a2 = fx * iz * swr
            b2 = (-fx * x * iz * iz + bf * iz * iz) * swr
            j = 2 * n + i
            A[0, j] = a2
            A[1, j] = 0.0
            A[2, j] = b2
            A[3, j] = b2 * y
            A[4, j] = a2 * z - b2 * x
            A[5, j] = -a2 * y
            r[j] = rs * swr


@njit(cache=True, nogil=True, error_model="numpy")
def inliers(Xc, u_obs, v_obs, ur, has_r, info, chi2, fx, fy, cx, cy, bf):  # pragma: no cover - compiled
    """Chi-square test of the information-weighted squared reprojection errors (``(n,)`` bool)."""
    n = u_obs.shape[0]
    out = np.empty(n, np.bool_)
    for i in range(n):
        zc = Xc[2, i]
        z = _nanmax(zc, 1e-6)
        iz = 1.0 / z
        du = (fx * Xc[0, i] * iz + cx) - u_obs[i]
        dv = (fy * Xc[1, i] * iz + cy) - v_obs[i]
        e2 = du * du + dv * dv
        if has_r[i]:
            ds = ((fx * Xc[0, i] * iz + cx) - bf / z) - ur[i]
            e2 = e2 + ds * ds
        else:
            e2 = e2 + 0.0
        e2 = e2 * info[i]
        out[i] = (e2 < chi2[i]) and (zc > 0)
    return out


@njit(cache=True, nogil=True, error_model="numpy")
def reproj_inliers(X_cam, x, K, threshold_px):  # pragma: no cover - compiled
    """``(mask, err)`` of ``pnp._reproj_inliers`` without distortion from the camera points
    ``X_cam (N, 3)``: pixel error ``|K [x / z, y / z] - x|`` and ``z > 0, finite, err < threshold``."""
    n = X_cam.shape[0]
    mask = np.empty(n, np.bool_)
    err = np.empty(n)
    for i in range(n):
        z = X_cam[i, 2]
        xn = X_cam[i, 0] / z
        yn = X_cam[i, 1] / z
        du = (K[0, 0] * xn + K[0, 1] * yn + K[0, 2]) - x[i, 0]
        dv = (K[1, 1] * yn + K[1, 2]) - x[i, 1]
        e = np.sqrt(du * du + dv * dv)
        err[i] = e
        mask[i] = (z > 0) and np.isfinite(e) and (e < threshold_px)
    return mask, err


@njit(cache=True, nogil=True, error_model="numpy")
def reproj_normal_equations(T, X, x, K, H, g):  # pragma: no cover - compiled
    """Squared reprojection error ``sum |pi(K (R X + t)) - x|^2`` at ``T (4, 4)`` (returned) and its
    Gauss-Newton normal equations ``H = J^T J (6, 6)``, ``g = J^T r (6,)`` (filled) for the left
    perturbation ``T <- [exp(phi), rho; 0, 1] T``, ``xi = (rho, phi)``.

    With ``Xc = R X + t``: ``d(Xc)/d(xi) = [I, -[Xc]x]`` and, for ``u = fx x/z + s y/z + cx``,
    ``v = fy y/z + cy``: ``du/dXc = (fx, s, -(fx x + s y)/z) / z``, ``dv/dXc = (0, fy, -fy y/z) / z``
    (Barfoot 2017, sec. 7.3.3); the residual is ``r = (u, v) - x``. No distortion.
    """
    n = X.shape[0]
    fx = K[0, 0]
    s = K[0, 1]
    cx = K[0, 2]
    fy = K[1, 1]
    cy = K[1, 2]
    J = np.empty((2, 6))
    for a in range(6):
        g[a] = 0.0
        for b in range(6):
            H[a, b] = 0.0
    cost = 0.0
    for i in range(n):
        X0 = X[i, 0]
        X1 = X[i, 1]
        X2 = X[i, 2]
        xc = T[0, 0] * X0 + T[0, 1] * X1 + T[0, 2] * X2 + T[0, 3]
        yc = T[1, 0] * X0 + T[1, 1] * X1 + T[1, 2] * X2 + T[1, 3]
        zc = T[2, 0] * X0 + T[2, 1] * X1 + T[2, 2] * X2 + T[2, 3]
        iz = 1.0 / zc
        xn = xc * iz
        yn = yc * iz
        ru = fx * xn + s * yn + cx - x[i, 0]
        rv = fy * yn + cy - x[i, 1]
        cost += ru * ru + rv * rv
        ax = fx * iz
        ay = s * iz
        az = -(fx * xn + s * yn) * iz
        cy_ = fy * iz
        cz = -fy * yn * iz
        J[0, 0] = ax
        J[0, 1] = ay
        J[0, 2] = az
        J[0, 3] = az * yc - ay * zc
        J[0, 4] = ax * zc - az * xc
        J[0, 5] = ay * xc - ax * yc
        J[1, 0] = 0.0
        J[1, 1] = cy_
        J[1, 2] = cz
        J[1, 3] = cz * yc - cy_ * zc
        J[1, 4] = -cz * xc
        J[1, 5] = cy_ * xc
        for a in range(6):
            ja = J[0, a]
            ka = J[1, a]
            g[a] += ja * ru + ka * rv
            for b in range(a, 6):
                H[a, b] += ja * J[0, b] + ka * J[1, b]
    for a in range(6):
        for b in range(a):
            H[a, b] = H[b, a]
    return cost


@njit(cache=True, nogil=True, error_model="numpy")
def so3_exp(w0, w1, w2, R):  # pragma: no cover - compiled
    """:func:`vslam.geometry.lie.so3_exp` of one vector into ``R (3, 3)``: Rodrigues' formula
    ``R = I + sin(a)/a [w]x + (1 - cos a)/a^2 [w]x^2`` (Sola eq. 77), the same series below 1e-8."""
    a = np.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
    if a < 1e-8:
        A = 1.0 - a * a / 6.0
        B = 0.5 - a * a / 24.0
    else:
        A = np.sin(a) / a
        B = (1.0 - np.cos(a)) / (a * a)
    aa = a * a
    R[0, 0] = 1.0 + B * (w0 * w0 - aa)
    R[1, 1] = 1.0 + B * (w1 * w1 - aa)
    R[2, 2] = 1.0 + B * (w2 * w2 - aa)
    R[0, 1] = -A * w2 + B * w0 * w1
    R[1, 0] = A * w2 + B * w0 * w1
    R[0, 2] = A * w1 + B * w0 * w2
    R[2, 0] = -A * w1 + B * w0 * w2
    R[1, 2] = -A * w0 + B * w1 * w2
    R[2, 1] = A * w0 + B * w1 * w2


@njit(cache=True, nogil=True, error_model="numpy")
def _solve_spd6(A, b, out):  # pragma: no cover - compiled
    """``out = A^-1 b`` for a symmetric positive definite ``A (6, 6)`` by Cholesky ``A = L L^T``
    (``A`` is overwritten by ``L``); False if a pivot is not positive (or NaN)."""
    for j in range(6):
        d = A[j, j]
        for k in range(j):
            d -= A[j, k] * A[j, k]
        if not d > 0.0:
            return False
        d = np.sqrt(d)
        A[j, j] = d
        for i in range(j + 1, 6):
            v = A[i, j]
            for k in range(j):
                v -= A[i, k] * A[j, k]
            A[i, j] = v / d
    for i in range(6):  # L y = b
        v = b[i]
        for k in range(i):
            v -= A[i, k] * out[k]
        out[i] = v / A[i, i]
    for i in range(5, -1, -1):  # L^T out = y
        v = out[i]
        for k in range(i + 1, 6):
            v -= A[k, i] * out[k]
        out[i] = v / A[i, i]
    return True


@njit(cache=True, nogil=True, error_model="numpy")
def nearest_rotation(M, R):  # pragma: no cover - compiled
    """:func:`vslam.geometry.lie.project_to_so3` of ``M (3, 3)`` into ``R``: the nearest rotation in the
    Frobenius norm, ``U diag(1, 1, det(U V^T)) V^T`` from the SVD ``M = U S V^T``."""
    U, _, Vt = np.linalg.svd(np.ascontiguousarray(M))
    for i in range(3):
        for j in range(3):
            R[i, j] = U[i, 0] * Vt[0, j] + U[i, 1] * Vt[1, j] + U[i, 2] * Vt[2, j]
    det = (R[0, 0] * (R[1, 1] * R[2, 2] - R[1, 2] * R[2, 1]) - R[0, 1] * (R[1, 0] * R[2, 2] - R[1, 2] * R[2, 0])
           + R[0, 2] * (R[1, 0] * R[2, 1] - R[1, 1] * R[2, 0]))
    if det < 0:
        for i in range(3):
            for j in range(3):
                R[i, j] = U[i, 0] * Vt[0, j] + U[i, 1] * Vt[1, j] - U[i, 2] * Vt[2, j]


@njit(cache=True, nogil=True, error_model="numpy")
def lm_reprojection(T0, X, x, K, max_iters, eps):  # pragma: no cover - compiled
    """Levenberg-Marquardt on SE(3) of the squared reprojection error from ``T0 (4, 4)``; returns
    ``T (4, 4)``. It starts from :func:`nearest_rotation` of ``T0``'s rotation, as OpenCV's LM starts
    from ``cv2.Rodrigues`` of it (an SVD too): the tracker's poses are products of earlier ones, whose
    round-off off SO(3) would otherwise grow from frame to frame (the updates keep it). Each step
    solves ``(H + lambda diag(H)) xi = -g`` (Marquardt 1963; ``H, g`` from
    :func:`reproj_normal_equations`, by Cholesky) and tries ``T <- [so3_exp(phi), rho; 0, 1] T``; a step that
    lowers the error is kept and ``lambda / 10``, otherwise ``lambda * 10``. Stops after
    ``max_iters`` steps, at a step with ``|xi|_inf < eps``, or when the damped system is singular.
    """
    T = T0.copy()
    dR = np.empty((3, 3))
    nearest_rotation(T0[:3, :3], dR)
    T[:3, :3] = dR
    Tn = np.empty((4, 4))
    H = np.empty((6, 6))
    g = np.empty(6)
    Hn = np.empty((6, 6))
    gn = np.empty(6)
    A = np.empty((6, 6))
    b = np.empty(6)
    xi = np.empty(6)
    cost = reproj_normal_equations(T, X, x, K, H, g)
    lam = 1e-3
    for _ in range(max_iters):
        for i in range(6):
            b[i] = -g[i]
            for j in range(6):
                A[i, j] = H[i, j]
            A[i, i] = H[i, i] * (1.0 + lam)
        if not _solve_spd6(A, b, xi):
            break
        so3_exp(xi[3], xi[4], xi[5], dR)
        for i in range(3):
            for j in range(4):
                Tn[i, j] = dR[i, 0] * T[0, j] + dR[i, 1] * T[1, j] + dR[i, 2] * T[2, j]
            Tn[i, 3] += xi[i]
        Tn[3, 0] = 0.0
        Tn[3, 1] = 0.0
        Tn[3, 2] = 0.0
        Tn[3, 3] = 1.0
        cost_n = reproj_normal_equations(Tn, X, x, K, Hn, gn)
        if cost_n < cost:  # NaN (a point crossing z = 0) is never kept
            cost = cost_n
            T[:, :] = Tn
            H[:, :] = Hn
            g[:] = gn
            lam *= 0.1
        else:
            lam *= 10.0
        step = 0.0
        for i in range(6):
            step = max(step, abs(xi[i]))
        if step < eps:
            break
    return T


def warm() -> None:
    """Call each kernel once on tiny inputs (loads the cached machine code)."""
    Xc = np.array([[0.1], [0.2], [2.0]])
    one = np.ones(1)
    has_r = np.ones(1, np.bool_)
    A = np.empty((6, 3))
    r = np.empty(3)
    linearize(Xc, one, one, one, has_r, one, one, has_r, 1.0, 1.0, 0.0, 0.0, 0.1, True, A, r)
    inliers(Xc, one, one, one, has_r, one, one, 1.0, 1.0, 0.0, 0.0, 0.1)
    reproj_inliers(np.ascontiguousarray(Xc.T), np.zeros((1, 2)), np.eye(3), 2.0)
    R = np.empty((3, 3))
    so3_exp(0.1, 0.2, 0.3, R)
    nearest_rotation(np.eye(3), R)
    reproj_normal_equations(np.eye(4), np.ascontiguousarray(Xc.T), np.zeros((1, 2)), np.eye(3), np.empty((6, 6)),
                            np.empty(6))
    lm_reprojection(np.eye(4), np.ascontiguousarray(Xc.T), np.zeros((1, 2)), np.eye(3), 1, 1e-10)
