"""Camera pose from 3D-2D correspondences (Perspective-n-Point) with RANSAC and LM refinement.

Minimal solver inside RANSAC: P3P (Kneip et al., CVPR 2011) / AP3P (Ke & Roumeliotis, CVPR 2017)
via OpenCV's ``solvePnPRansac``; refinement: Levenberg-Marquardt on SE(3) of the reprojection error
(:func:`pnp_kernels.lm_reprojection`; ``cv2.solvePnPRefineLM`` with distortion) over the inliers, then the
inliers are re-selected and refined again.
On 500 points with 30 % outliers this takes a few milliseconds (see benchmarks/geometry_bench.py).

Failure contract: :func:`solve_pnp` raises :class:`vslam.errors.GeometryError` (fewer than 4
points, NaN/inf, collinear points, no consensus, fewer than ``min_inliers`` inliers); it never
returns ``None``.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np

from vslam.errors import GeometryError
from vslam.geometry import pnp_kernels
from vslam.geometry.lie import make_T, so3_exp

log = logging.getLogger(__name__)

USE_KERNELS = True  # refine_pose's per-point work by pnp_kernels (identical results); False: NumPy

_FLAGS = {"p3p": "SOLVEPNP_P3P", "ap3p": "SOLVEPNP_AP3P", "epnp": "SOLVEPNP_EPNP", "sqpnp": "SOLVEPNP_SQPNP"}


def project_points(
    T_cam_world: np.ndarray, K: np.ndarray, X_world: np.ndarray, dist: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Pixels ``(N, 2)`` of world points and their camera depths ``z`` ``(N,)`` (radtan if ``dist``)."""
    T = np.asarray(T_cam_world, float)
    X_cam = np.asarray(X_world, float) @ T[:3, :3].T + T[:3, 3]
    z = X_cam[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        xn = X_cam[:, :2] / z[:, None]
    if dist is not None and np.any(np.asarray(dist) != 0):
        k1, k2, p1, p2, k3 = np.r_[np.asarray(dist, float).ravel(), np.zeros(5)][:5]
        x, y = xn[:, 0], xn[:, 1]
        r2 = x * x + y * y
        rad = 1 + k1 * r2 + k2 * r2 * r2 + k3 * r2**3
        xn = np.stack([x * rad + 2 * p1 * x * y + p2 * (r2 + 2 * x * x),
                       y * rad + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y], axis=1)
    K = np.asarray(K, float)
    uv = np.stack([K[0, 0] * xn[:, 0] + K[0, 1] * xn[:, 1] + K[0, 2], K[1, 1] * xn[:, 1] + K[1, 2]], axis=1)
    return uv, z


def _reproj_inliers(T, K, X, x, dist, threshold_px):
    if USE_KERNELS and dist is None and X.dtype == x.dtype == K.dtype == np.float64:
        T = np.asarray(T, float)
        return pnp_kernels.reproj_inliers(X @ T[:3, :3].T + T[:3, 3], x, K, float(threshold_px))
    uv, z = project_points(T, K, X, dist)
    err = np.linalg.norm(uv - x, axis=1)
    return (z > 0) & np.isfinite(err) & (err < threshold_px), err


def _to_T(rvec: np.ndarray, tvec: np.ndarray) -> np.ndarray:

    return make_T(cv2.Rodrigues(np.asarray(rvec, float))[0], np.asarray(tvec, float).ravel())


LM_MAX_ITERS = 20  # cv2.solvePnPRefineLM's criteria as solve_pnp used them: COUNT 20, EPS 1e-10
LM_EPS = 1e-10


def _refine_lm(T, K, X, x, dist, threshold_px, rounds: int = 2):
    """LM on the inliers of ``T``, re-selecting the inliers after each round.

    Undistorted pixels: :func:`pnp_kernels.lm_reprojection`, Levenberg-Marquardt on SE(3) of the
    plain squared reprojection error with the left update ``T <- [so3_exp(phi), rho; 0, 1] T`` (as
    :func:`refine_pose`) and ``cv2.solvePnPRefineLM``'s criteria (at most ``LM_MAX_ITERS`` steps,
    stop at a step below ``LM_EPS``); it reaches the same minimum as ``cv2.solvePnPRefineLM``
    (tests/geometry/test_pnp_lm.py) in about 5 steps instead of 20; as OpenCV's, it starts from the
    nearest rotation to ``T``'s. With distortion: OpenCV's.
    """
    import cv2

    mask, _ = _reproj_inliers(T, K, X, x, dist, threshold_px)
    own = dist is None and X.dtype == x.dtype == K.dtype == np.float64
    for _ in range(rounds):
        if mask.sum() < 4:
            break
        if own:
            T = pnp_kernels.lm_reprojection(np.ascontiguousarray(T, dtype=np.float64), X[mask], x[mask],
                                            np.ascontiguousarray(K), LM_MAX_ITERS, LM_EPS)
        else:
            rvec = cv2.Rodrigues(T[:3, :3])[0]
            tvec = T[:3, 3].reshape(3, 1).copy()
            rvec, tvec = cv2.solvePnPRefineLM(
                X[mask], x[mask], K, dist, rvec, tvec,
                (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, LM_MAX_ITERS, LM_EPS),
            )
            T = _to_T(rvec, tvec)
        new, _ = _reproj_inliers(T, K, X, x, dist, threshold_px)
        if np.array_equal(new, mask):
            break
        mask = new
    return T, mask


def solve_pnp(
    X_world: np.ndarray, x: np.ndarray, K: np.ndarray, dist: np.ndarray | None = None,
    T_cam_world_init: np.ndarray | None = None, threshold_px: float = 2.0,
    confidence: float = 0.999, max_iters: int = 300, min_inliers: int = 6,
    method: Literal["p3p", "ap3p", "epnp", "sqpnp"] = "p3p", init_gate: float = 3.0,
    refine_rounds: int = 2,
) -> tuple[np.ndarray, np.ndarray]:
    """``T_cam_world`` from world points and their pixels: RANSAC + Levenberg-Marquardt.

    With ``T_cam_world_init`` (e.g. a constant-velocity prediction while tracking), the guess is
    tried first: LM from it on the points within ``init_gate * threshold_px``; if the refined pose
    keeps at least half of the points as inliers RANSAC is skipped, otherwise RANSAC runs as usual.

    Args:
        X_world: ``(N, 3)`` points in the world frame, ``N >= 4``.
        x: ``(N, 2)`` observed pixels (distorted if ``dist`` is given, ideal otherwise).
        K: 3x3 intrinsics. dist: OpenCV distortion ``(k1, k2, p1, p2, k3)`` or ``None``.
        threshold_px: inlier threshold on the reprojection error, pixels.
        min_inliers: fewer final inliers raise :class:`GeometryError` (capped at ``N``, at least 4).
        method: minimal solver inside RANSAC (``p3p`` is the fastest; ``sqpnp``/``epnp`` also work).
        refine_rounds: LM rounds (each re-selecting the inliers) after the initial guess's gated
            round; 1 when a later refinement follows anyway.

    Returns:
        ``(T_cam_world (4, 4), inlier_mask (N,) bool)``.

    Raises:
        GeometryError: too few / non-finite / collinear points, or no pose with enough inliers.
    """
    import cv2

    X = np.ascontiguousarray(X_world, dtype=np.float64)
    x = np.ascontiguousarray(x, dtype=np.float64)
    K = np.asarray(K, dtype=np.float64)
    if X.ndim != 2 or X.shape[1] != 3 or x.shape != (X.shape[0], 2):
        raise GeometryError(f"solve_pnp needs (N, 3) points and (N, 2) pixels, got {X.shape} and {x.shape}")
    n = X.shape[0]
    if n < 4:
        raise GeometryError(f"solve_pnp needs at least 4 correspondences, got {n}")
    if not (np.all(np.isfinite(X)) and np.all(np.isfinite(x))):
        raise GeometryError("solve_pnp got NaN or inf coordinates; drop those correspondences first")
    if K.shape != (3, 3) or not np.all(np.isfinite(K)):
        raise GeometryError(f"solve_pnp: K must be a finite 3x3 matrix, got {K!r}")
    if method not in _FLAGS:
        raise GeometryError(f"unknown PnP method {method!r}; use one of {sorted(_FLAGS)}")
    sv = np.linalg.svd(X - X.mean(axis=0), compute_uv=False)
    if sv[1] < 1e-9 * max(sv[0], 1e-300):
        raise GeometryError("solve_pnp: the 3D points are collinear (or coincident); the pose is undetermined")
    d = None if dist is None else np.asarray(dist, dtype=np.float64).ravel()
    need = max(4, min(min_inliers, n))  # with only 4-5 points, all of them must agree

    if T_cam_world_init is not None:
        T0 = np.asarray(T_cam_world_init, float)
        if T0.shape != (4, 4) or not np.all(np.isfinite(T0)):
            raise GeometryError(f"solve_pnp: T_cam_world_init must be a finite 4x4 matrix, got shape {T0.shape}")
        gate, _ = _reproj_inliers(T0, K, X, x, d, init_gate * threshold_px)
        if gate.sum() >= need:
            T, mask = _refine_lm(T0, K, X, x, d, init_gate * threshold_px, rounds=1)
            T, mask = _refine_lm(T, K, X, x, d, threshold_px, rounds=refine_rounds)
            if mask.sum() >= max(need, 0.5 * n):
                return T, mask
        log.debug("solve_pnp: the initial guess explains too few points; running RANSAC")

    ok, rvec, tvec, idx = cv2.solvePnPRansac(
        X, x, K, d, iterationsCount=max_iters, reprojectionError=float(threshold_px),
        confidence=confidence, flags=getattr(cv2, _FLAGS[method]),
    )
    if not ok or idx is None or len(idx) < 4:
        raise GeometryError(f"solve_pnp: RANSAC found no pose consistent with >= 4 of {n} correspondences")
    T, mask = _refine_lm(_to_T(rvec, tvec), K, X, x, d, threshold_px)
    if mask.sum() < need:
        raise GeometryError(
            f"solve_pnp: only {int(mask.sum())} of {n} correspondences are inliers (< {need}) "
            f"at {threshold_px} px"
        )
    return T, mask


def reprojection_errors(
    T_cam_world: np.ndarray, K: np.ndarray, X_world: np.ndarray, x: np.ndarray, dist: np.ndarray | None = None
) -> np.ndarray:
    """Euclidean reprojection error per point, pixels (``inf`` for points behind the camera)."""
    uv, z = project_points(T_cam_world, K, X_world, dist)
    err = np.linalg.norm(uv - np.asarray(x, float), axis=1)
    return np.where(z > 0, err, np.inf)


# ----------------------------------------------------------------------------- tracking
CHI2_2DOF = 5.991  # 95% chi-square quantiles (ORB-SLAM PoseOptimization thresholds)
CHI2_3DOF = 7.815


def pnp_ransac(
    X_world: np.ndarray,
    uv: np.ndarray,
    K: np.ndarray,
    T_cam_world_guess: np.ndarray | None = None,
    reproj_px: float = 3.0,
    iterations: int = 100,
    refine_rounds: int = 2,
) -> tuple[np.ndarray | None, np.ndarray]:
    """PnP on undistorted pixels (:func:`solve_pnp`: LM from the guess when it
    explains enough points, else RANSAC with P3P); returns ``(T_cam_world or None, inlier mask)``."""
    n = len(X_world)
    mask = np.zeros(n, dtype=bool)
    if n < 6:
        return None, mask
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


@dataclass
class _PoseResiduals:
    """The fixed data of :func:`refine_pose`: points ``(3, n)``, observations, information and the
    Huber/chi-square thresholds per point (3 dof where a right-camera ``u_r`` is observed)."""

    Xt: np.ndarray
    u_obs: np.ndarray
    v_obs: np.ndarray
    ur: np.ndarray
    has_r: np.ndarray
    info: np.ndarray
    delta: np.ndarray
    chi2: np.ndarray
    fx: float
    fy: float
    cx: float
    cy: float
    bf: float

    @classmethod
    def build(cls, X_world, uv, K, sigma, u_right, bf) -> _PoseResiduals:
        n = len(X_world)
        has_r = np.zeros(n, bool) if u_right is None else np.isfinite(u_right)
        return cls(
            Xt=np.ascontiguousarray(np.asarray(X_world, float).T),  # (3, n): rows x, y, z
            u_obs=np.ascontiguousarray(uv[:, 0], dtype=float),
            v_obs=np.ascontiguousarray(uv[:, 1], dtype=float),
            ur=np.zeros(n) if u_right is None else np.where(has_r, u_right, 0.0).astype(float),
            has_r=has_r,
            info=np.ones(n) if sigma is None else 1.0 / np.asarray(sigma, float) ** 2,
            delta=np.where(has_r, np.sqrt(CHI2_3DOF), np.sqrt(CHI2_2DOF)),
            chi2=np.where(has_r, CHI2_3DOF, CHI2_2DOF),
            fx=float(K[0, 0]), fy=float(K[1, 1]), cx=float(K[0, 2]), cy=float(K[1, 2]), bf=float(bf),
        )

    def project(self, T: np.ndarray):
        """Camera points ``Xc (3, n)``, clamped depth ``z``, ``1 / z`` and the pixels ``u, v``."""
        Xc = T[:3, :3] @ self.Xt + T[:3, 3:4]
        z = np.maximum(Xc[2], 1e-6)
        iz = 1.0 / z
        return Xc, z, iz, self.fx * Xc[0] * iz + self.cx, self.fy * Xc[1] * iz + self.cy

    def linearize(self, T: np.ndarray, inl: np.ndarray, A: np.ndarray, r: np.ndarray, any_r: bool) -> None:
        """Fill the Huber-weighted Jacobian ``A (6, m n)`` and residuals ``r (m n,)`` at ``T``
        (rows: ``u_1..u_n, v_1..v_n[, ur_1..ur_n]``); outliers and points behind get weight 0."""
        if USE_KERNELS:
            Xc = T[:3, :3] @ self.Xt + T[:3, 3:4]
            pnp_kernels.linearize(Xc, self.u_obs, self.v_obs, self.ur, self.has_r, self.info, self.delta, inl,
                                  self.fx, self.fy, self.cx, self.cy, self.bf, any_r, A, r)
            return
        n = len(self.u_obs)
        fx, fy, bf, has_r = self.fx, self.fy, self.bf, self.has_r
        Xc, z, iz, u_hat, v_hat = self.project(T)
        x, y = Xc[0], Xc[1]
        ru = u_hat - self.u_obs
        rv = v_hat - self.v_obs
        rs = np.where(has_r, (u_hat - bf * iz) - self.ur, 0.0)
        e = np.sqrt(self.info * (ru * ru + rv * rv + rs * rs))
        w = self.info * np.where(e <= self.delta, 1.0, self.delta / np.maximum(e, 1e-12))
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

    def inliers(self, T: np.ndarray) -> np.ndarray:
        """Chi-square test of the (information-weighted) squared reprojection errors at ``T``."""
        if USE_KERNELS:
            return pnp_kernels.inliers(T[:3, :3] @ self.Xt + T[:3, 3:4], self.u_obs, self.v_obs, self.ur,
                                       self.has_r, self.info, self.chi2, self.fx, self.fy, self.cx, self.cy, self.bf)
        Xc, z, iz, u_hat, v_hat = self.project(T)
        e2 = (u_hat - self.u_obs) ** 2 + (v_hat - self.v_obs) ** 2
        e2 += np.where(self.has_r, ((u_hat - self.bf / z) - self.ur) ** 2, 0.0)
        e2 *= self.info
        return (e2 < self.chi2) & (Xc[2] > 0)


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
    res = _PoseResiduals.build(X_world, uv, K, sigma, u_right, bf)
    any_r = bool(res.has_r.any())
    m = 3 if any_r else 2
    A = np.empty((6, m * n))  # rows: d(residual)/d(xi_k), residuals u_1..u_n, v_1..v_n[, ur_1..ur_n]
    r = np.empty(m * n)
    inl = np.ones(n, dtype=bool)
    for _ in range(rounds):
        for _ in range(iterations):
            res.linearize(T, inl, A, r, any_r)
            H = A @ A.T
            g = A @ r
            try:
                dx = -np.linalg.solve(H + 1e-9 * np.eye(6), g)
            except np.linalg.LinAlgError:
                break
            dT = np.eye(4)
            dT[:3, :3] = so3_exp(dx[3:])
            dT[:3, 3] = dx[:3]
            T = dT @ T
            if np.linalg.norm(dx) < 1e-5:
                break
        inl = res.inliers(T)
        if inl.sum() < 6:
            break
    return T, inl
