"""Compiled (numba) per-point kernels of :func:`vslam.geometry.pnp.refine_pose` and of the
inlier selection of :func:`vslam.geometry.pnp.solve_pnp`.

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
