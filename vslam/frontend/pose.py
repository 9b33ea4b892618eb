"""Per-frame pose estimators used by the tracker: PnP (3D-2D), 3D-3D alignment, essential matrix
(2D-2D), pose-only Gauss-Newton refinement, two-view triangulation. All vectorized over points."""
from __future__ import annotations

import logging

import cv2
import numpy as np

log = logging.getLogger(__name__)

CHI2_2DOF = 5.991  # 95% chi-square quantiles (ORB-SLAM PoseOptimization thresholds)
CHI2_3DOF = 7.815


def inv_T(T: np.ndarray) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3] = T[:3, :3].T
    out[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return out


def make_T(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = np.asarray(t).reshape(3)
    return T


def _so3_exp(w: np.ndarray) -> np.ndarray:
    R, _ = cv2.Rodrigues(np.asarray(w, dtype=np.float64).reshape(3, 1))
    return R


def pnp_ransac(
    X_world: np.ndarray,
    uv: np.ndarray,
    K: np.ndarray,
    T_cam_world_guess: np.ndarray | None = None,
    reproj_px: float = 3.0,
    iterations: int = 100,
    refine_rounds: int = 2,
) -> tuple[np.ndarray | None, np.ndarray]:
    """PnP on undistorted pixels (:func:`vslam.geometry.pnp.solve_pnp`: LM from the guess when it
    explains enough points, else RANSAC with P3P); returns ``(T_cam_world or None, inlier mask)``."""
    n = len(X_world)
    mask = np.zeros(n, dtype=bool)
    if n < 6:
        return None, mask
    from vslam.errors import GeometryError
    from vslam.geometry.pnp import solve_pnp

    try:
        T, m = solve_pnp(X_world, uv, K, T_cam_world_init=T_cam_world_guess, threshold_px=reproj_px,
                         max_iters=iterations, refine_rounds=refine_rounds)
        return np.asarray(T, dtype=float), np.asarray(m, dtype=bool)
    except GeometryError:
        return None, mask


def _horizontal_rows(out: np.ndarray, a: np.ndarray, b: np.ndarray, x, y, z) -> None:
    """``out (6, n)`` = d(u)/d(xi) of ``u = fx x / z + cx`` (or ``u_r = u - bf / z``) for
    ``T <- exp(xi) T``: ``d(u)/d(Xc) [I, -[Xc]x]`` with ``a = du/dx``, ``b = du/dz`` (weighted)."""
    out[0] = a
    out[1] = 0.0
    out[2] = b
    np.multiply(b, y, out=out[3])
    np.subtract(a * z, b * x, out=out[4])
    np.multiply(-a, y, out=out[5])


def _vertical_rows(out: np.ndarray, c: np.ndarray, d: np.ndarray, x, y, z) -> None:
    """``out (6, n)`` = d(v)/d(xi) of ``v = fy y / z + cy``, ``c = dv/dy``, ``d = dv/dz`` (weighted)."""
    out[0] = 0.0
    out[1] = c
    out[2] = d
    np.subtract(d * y, c * z, out=out[3])
    np.multiply(-d, x, out=out[4])
    np.multiply(c, x, out=out[5])


def refine_pose(
    T_cam_world: np.ndarray,
    X_world: np.ndarray,
    uv: np.ndarray,
    K: np.ndarray,
    sigma: np.ndarray | None = None,
    u_right: np.ndarray | None = None,
    bf: float = 0.0,
    rounds: int = 3,
    iterations: int = 5,
) -> tuple[np.ndarray, np.ndarray]:
    """Pose-only Gauss-Newton with Huber weights on reprojection residuals ``(u, v)`` and, where
    ``u_right`` is finite, the virtual right-camera residual ``u_r = u - bf / z`` (ORB-SLAM2's
    stereo/RGB-D pose optimization, Mur-Artal & Tardos 2017, eq. (2)-(3)). Outliers are reclassified
    each round by the chi-square test. Left perturbation ``T <- exp(xi) T``, ``xi = (rho, phi)``.

    The Jacobian rows of all residuals fill one ``(6, 3n)`` array in place, so the normal
    equations are one BLAS product per iteration.

    Returns ``(T_cam_world, inlier mask)``.
    """
    n = len(X_world)
    T = T_cam_world.copy()
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    info = np.ones(n) if sigma is None else 1.0 / np.asarray(sigma, float) ** 2
    has_r = np.zeros(n, bool) if u_right is None else np.isfinite(u_right)
    ur = np.zeros(n) if u_right is None else np.where(has_r, u_right, 0.0)
    delta = np.where(has_r, np.sqrt(CHI2_3DOF), np.sqrt(CHI2_2DOF))
    chi2 = np.where(has_r, CHI2_3DOF, CHI2_2DOF)
    Xt = np.ascontiguousarray(np.asarray(X_world, float).T)  # (3, n): rows x, y, z
    u_obs = np.ascontiguousarray(uv[:, 0], dtype=float)
    v_obs = np.ascontiguousarray(uv[:, 1], dtype=float)
    any_r = bool(has_r.any())
    m = 3 if any_r else 2
    A = np.empty((6, m * n))  # rows: d(residual)/d(xi_k), residuals u_1..u_n, v_1..v_n[, ur_1..ur_n]
    r = np.empty(m * n)
    inl = np.ones(n, dtype=bool)

    def project(T):
        Xc = T[:3, :3] @ Xt + T[:3, 3:4]
        z = np.maximum(Xc[2], 1e-6)
        iz = 1.0 / z
        return Xc, z, iz, fx * Xc[0] * iz + cx, fy * Xc[1] * iz + cy

    for _ in range(rounds):
        for _ in range(iterations):
            Xc, z, iz, u_hat, v_hat = project(T)
            x, y = Xc[0], Xc[1]
            ru = u_hat - u_obs
            rv = v_hat - v_obs
            rs = np.where(has_r, (u_hat - bf * iz) - ur, 0.0)
            e = np.sqrt(info * (ru * ru + rv * rv + rs * rs))
            w = info * np.where(e <= delta, 1.0, delta / np.maximum(e, 1e-12))
            w[~(inl & (Xc[2] > 0))] = 0.0
            sw = np.sqrt(w)
            a = fx * iz * sw
            c = fy * iz * sw
            b = -fx * x * iz * iz * sw
            d = -fy * y * iz * iz * sw
            _horizontal_rows(A[:, :n], a, b, x, y, z)
            _vertical_rows(A[:, n:2 * n], c, d, x, y, z)
            r[:n] = ru * sw
            r[n:2 * n] = rv * sw
            if any_r:
                swr = sw * has_r
                _horizontal_rows(A[:, 2 * n:], fx * iz * swr, (-fx * x * iz * iz + bf * iz * iz) * swr, x, y, z)
                r[2 * n:] = rs * swr
            H = A @ A.T
            g = A @ r
            try:
                dx = -np.linalg.solve(H + 1e-9 * np.eye(6), g)
            except np.linalg.LinAlgError:
                break
            dT = np.eye(4)
            dT[:3, :3] = _so3_exp(dx[3:])
            dT[:3, 3] = dx[:3]
            T = dT @ T
            if np.linalg.norm(dx) < 1e-5:
                break
        Xc, z, iz, u_hat, v_hat = project(T)
        e2 = (u_hat - u_obs) ** 2 + (v_hat - v_obs) ** 2
        e2 += np.where(has_r, ((u_hat - bf / z) - ur) ** 2, 0.0)
        e2 *= info
        inl = (e2 < chi2) & (Xc[2] > 0)
        if inl.sum() < 6:
            break
    return T, inl


def kabsch_batch(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Batched rigid alignment ``dst ~ R src + t`` (Arun et al. 1987 / Umeyama 1991 without scale)
    of ``(H, m, 3)`` point sets; returns ``R (H, 3, 3), t (H, 3)``."""
    ms, md = src.mean(axis=1), dst.mean(axis=1)
    C = np.einsum("hni,hnj->hij", dst - md[:, None], src - ms[:, None])
    U, _, Vt = np.linalg.svd(C)
    d = np.sign(np.linalg.det(U @ Vt))
    S = np.tile(np.eye(3), (len(src), 1, 1))
    S[:, 2, 2] = d
    R = U @ S @ Vt
    t = md - np.einsum("hij,hj->hi", R, ms)
    return R, t


def align_ransac(
    X_src: np.ndarray, X_dst: np.ndarray, threshold: np.ndarray | float, iterations: int = 200,
    rng: np.random.Generator | None = None,
) -> tuple[np.ndarray | None, np.ndarray]:
    """3D-3D RANSAC (3-point minimal sets, all hypotheses scored at once), then least squares on
    the inliers, re-scored twice. Returns ``(T_dst_src or None, inlier mask)``."""
    n = len(X_src)
    if n < 6:
        return None, np.zeros(n, bool)
    rng = rng or np.random.default_rng(0)
    thr2 = np.broadcast_to(np.asarray(threshold, float) ** 2, (n,))
    idx = np.stack([rng.choice(n, 3, replace=False) for _ in range(iterations)]) if n < 50 else \
        rng.integers(0, n, size=(iterations, 3))
    R, t = kabsch_batch(X_src[idx], X_dst[idx])
    pred = np.matmul(X_src[None], R.transpose(0, 2, 1)) + t[:, None, :]
    err2 = ((pred - X_dst[None]) ** 2).sum(axis=2)
    score = (err2 < thr2[None]).sum(axis=1)
    best = int(np.argmax(score))
    mask = err2[best] < thr2
    T = None
    for _ in range(3):
        if mask.sum() < 6:
            return None, mask
        Rb, tb = kabsch_batch(X_src[mask][None], X_dst[mask][None])
        T = make_T(Rb[0], tb[0])
        e2 = ((X_src @ T[:3, :3].T + T[:3, 3] - X_dst) ** 2).sum(axis=1)
        mask = e2 < thr2
    return T, mask


def essential_pose(
    uv1: np.ndarray, uv2: np.ndarray, K: np.ndarray, threshold_px: float = 1.0, min_parallax_deg: float = 0.5,
) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray, str]:
    """Relative pose from undistorted pixel matches: ``x2 = R x1 + t`` with ``|t| = 1`` (five-point
    RANSAC + cheirality, :func:`vslam.geometry.epipolar.relative_pose`).

    Returns ``(R, t, inlier mask, status)``: status ``ok``; ``rotation`` when the median
    rotation-compensated parallax is below ``min_parallax_deg`` (then ``t`` is zero and ``R`` the
    best rotation-only fit); ``failed`` (R None).
    """
    from vslam.errors import GeometryError
    from vslam.geometry.epipolar import bearings, normalize_points, relative_pose, rotation_only_fit

    n = len(uv1)
    if n < 8:
        return None, None, np.zeros(n, bool), "failed"
    f1 = bearings(normalize_points(uv1, K))
    f2 = bearings(normalize_points(uv2, K))
    R_rot, par = rotation_only_fit(f1, f2)
    if float(np.median(par)) < min_parallax_deg:
        return R_rot, np.zeros(3), par < 3.0 * max(float(np.median(par)), 0.05), "rotation"
    try:
        R, t, mask = relative_pose(uv1, uv2, K, threshold_px=threshold_px, min_parallax_deg=min_parallax_deg)
    except GeometryError as e:
        log.debug("essential_pose: %s", e)
        if "rotation" in str(e):  # parallax too small against the epipolar noise
            med = max(float(np.median(par)), 0.05)
            return R_rot, np.zeros(3), par < 3.0 * med, "rotation"
        return None, None, np.zeros(n, bool), "failed"
    return np.asarray(R), np.asarray(t).reshape(3), np.asarray(mask, bool), "ok"


def triangulate(
    T_cam1_world: np.ndarray, T_cam2_world: np.ndarray, K: np.ndarray, uv1: np.ndarray, uv2: np.ndarray,
) -> np.ndarray:
    """Linear (DLT) two-view triangulation of undistorted pixels (Hartley & Zisserman 12.2);
    returns world points ``(N, 3)``."""
    P1 = K @ T_cam1_world[:3]
    P2 = K @ T_cam2_world[:3]
    Xh = cv2.triangulatePoints(P1, P2, uv1.T.astype(np.float64), uv2.T.astype(np.float64))
    w = Xh[3]
    w = np.where(np.abs(w) < 1e-12, 1e-12, w)
    return (Xh[:3] / w).T


def reprojection_error(T_cam_world: np.ndarray, K: np.ndarray, X_world: np.ndarray, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(pixel error (N,), depth (N,))`` of world points in a camera."""
    Xc = X_world @ T_cam_world[:3, :3].T + T_cam_world[:3, 3]
    z = Xc[:, 2]
    zs = np.where(np.abs(z) < 1e-9, 1e-9, z)
    u = K[0, 0] * Xc[:, 0] / zs + K[0, 2]
    v = K[1, 1] * Xc[:, 1] / zs + K[1, 2]
    return np.hypot(u - uv[:, 0], v - uv[:, 1]), z


def parallax_deg(T_world_cam1: np.ndarray, T_world_cam2: np.ndarray, X_world: np.ndarray) -> np.ndarray:
    """Angle at each point between the rays to the two camera centres."""
    a = X_world - T_world_cam1[:3, 3]
    b = X_world - T_world_cam2[:3, 3]
    c = np.einsum("ij,ij->i", a, b) / np.maximum(np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1), 1e-12)
    return np.degrees(np.arccos(np.clip(c, -1, 1)))
