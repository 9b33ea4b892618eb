"""The essential matrix itself: input checks, normalized coordinates, the normalized 8-point
algorithm, epipolar residuals (algebraic and Sampson), F <-> E conversions and the decomposition
``E = [t]x R``.

Convention: ``x2^T E x1 = 0`` with ``E = [t]x R`` and ``X_2 = R X_1 + t`` (``T_cam2_cam1``); see
:mod:`vslam.geometry.epipolar` for the failure contract and references.
"""
from __future__ import annotations

import numpy as np

from vslam.errors import GeometryError
from vslam.geometry.lie import hat

_W = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])


# ----------------------------------------------------------------------------- input checks
def check_pairs(x1: np.ndarray, x2: np.ndarray, n_min: int, what: str) -> tuple[np.ndarray, np.ndarray]:
    x1 = np.asarray(x1, dtype=float)
    x2 = np.asarray(x2, dtype=float)
    if x1.ndim != 2 or x1.shape[1] != 2 or x1.shape != x2.shape:
        raise GeometryError(f"{what} needs two (N, 2) arrays of equal shape, got {x1.shape} and {x2.shape}")
    if x1.shape[0] < n_min:
        raise GeometryError(f"{what} needs at least {n_min} correspondences, got {x1.shape[0]}")
    if not (np.all(np.isfinite(x1)) and np.all(np.isfinite(x2))):
        raise GeometryError(f"{what} got NaN or inf coordinates; drop those correspondences first")
    return x1, x2


def check_K(K: np.ndarray) -> np.ndarray:
    K = np.asarray(K, dtype=float)
    if K.shape != (3, 3) or not np.all(np.isfinite(K)) or abs(np.linalg.det(K)) < 1e-12:
        raise GeometryError(f"K must be a finite invertible 3x3 intrinsic matrix, got {K!r}")
    return K


def check_not_collinear(x: np.ndarray, what: str, tol_px: float) -> None:
    """Raise when the pixels ``(N, 2)`` lie on one line (minor-axis std below ``tol_px``): the
    epipolar geometry of points on a line (a 3D line, or a plane through a camera centre) is
    undetermined."""
    c = x - x.mean(axis=0)
    ev = np.linalg.eigvalsh(c.T @ c / max(len(x), 1))
    minor, major = np.sqrt(np.maximum(ev, 0.0))
    if minor < max(tol_px, 1e-6 * major):
        raise GeometryError(
            f"{what}: the inlier pixels lie on a line (spread {minor:.2g} px across vs {major:.3g} px along); "
            "the relative pose is undetermined (points on a 3D line or on a plane through a camera centre)"
        )


def normalize_points(x: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Pixels ``(N, 2)`` -> normalized image coordinates ``(N, 2)`` through ``K^-1``."""
    K = check_K(K)
    x = np.asarray(x, dtype=float)
    y = (x[:, 1] - K[1, 2]) / K[1, 1]
    return np.stack([(x[:, 0] - K[0, 2] - K[0, 1] * y) / K[0, 0], y], axis=1)


def bearings(xn: np.ndarray) -> np.ndarray:
    """Normalized coordinates ``(N, 2)`` -> unit rays ``(N, 3)``."""
    f = np.concatenate([xn, np.ones((len(xn), 1))], axis=1)
    return f / np.linalg.norm(f, axis=1, keepdims=True)


# ----------------------------------------------------------------------------- 8-point
def _hartley_transform(x: np.ndarray) -> np.ndarray:
    """Similarity moving the centroid to 0 and the mean distance to sqrt(2) (Hartley 1997, sec. 4)."""
    c = x.mean(axis=0)
    d = np.mean(np.linalg.norm(x - c, axis=1))
    if not np.isfinite(d) or d < 1e-15:
        raise GeometryError("all points coincide; the epipolar geometry is undetermined")
    s = np.sqrt(2.0) / d
    return np.array([[s, 0.0, -s * c[0]], [0.0, s, -s * c[1]], [0.0, 0.0, 1.0]])


def project_to_essential(M: np.ndarray) -> np.ndarray:
    """Closest essential matrix in the Frobenius norm: ``U diag(1, 1, 0) V^T`` (HZ sec. 9.6.1).

    The result has unit singular values, so ``||E||_F = sqrt(2)``.
    """
    U, _, Vt = np.linalg.svd(np.asarray(M, dtype=float))
    return U @ np.diag([1.0, 1.0, 0.0]) @ Vt


def essential_8point(x1n: np.ndarray, x2n: np.ndarray) -> np.ndarray:
    """Normalized 8-point essential matrix from ``N >= 8`` correspondences in normalized coordinates.

    Each pair gives one row of ``A e = 0`` from ``x2^T E x1 = 0`` (Longuet-Higgins 1981);
    the points are first conditioned by Hartley's similarity ``T`` (Hartley 1997), ``e`` is the
    right singular vector of the smallest singular value, ``E = T2^T E_hat T1``, and finally
    ``E`` is projected onto the essential manifold (two equal singular values, one zero).

    Args:
        x1n, x2n: ``(N, 2)`` normalized image coordinates in views 1 and 2.

    Returns:
        ``E`` (3, 3) with singular values ``(1, 1, 0)``.

    Raises:
        GeometryError: fewer than 8 pairs, NaN/inf, or a rank-deficient system (e.g. all points
        on a line, or too few distinct points).

    Example:
        >>> E = essential_8point(x1n, x2n)  # doctest: +SKIP
    """
    x1n, x2n = check_pairs(x1n, x2n, 8, "essential_8point")
    T1 = _hartley_transform(x1n)
    T2 = _hartley_transform(x2n)
    a = x1n * T1[0, 0] + T1[:2, 2]
    b = x2n * T2[0, 0] + T2[:2, 2]
    A = np.zeros((max(len(a), 9), 9))  # zero rows keep the SVD square when N == 8
    n = len(a)
    A[:n, 0:3] = b[:, :1] * np.c_[a, np.ones(n)]
    A[:n, 3:6] = b[:, 1:2] * np.c_[a, np.ones(n)]
    A[:n, 6:8] = a
    A[:n, 8] = 1.0
    _, S, Vt = np.linalg.svd(A, full_matrices=False)
    if S.shape[0] < 9 or S[7] < 1e-10 * S[0]:
        raise GeometryError(
            "essential_8point: the linear system has a null space of dimension > 1 "
            "(degenerate configuration: too few distinct points or points on a line)"
        )
    E_hat = Vt[-1].reshape(3, 3)
    return project_to_essential(T2.T @ E_hat @ T1)


# ----------------------------------------------------------------------------- residuals
def epipolar_residual(E: np.ndarray, x1n: np.ndarray, x2n: np.ndarray) -> np.ndarray:
    """Algebraic residuals ``x2^T E x1`` ``(N,)`` for normalized coordinates."""
    h1 = np.c_[np.asarray(x1n, float), np.ones(len(x1n))]
    h2 = np.c_[np.asarray(x2n, float), np.ones(len(x2n))]
    return np.einsum("ni,ij,nj->n", h2, np.asarray(E, float), h1)


def sampson_distance(F: np.ndarray, x1: np.ndarray, x2: np.ndarray, signed: bool = False) -> np.ndarray:
    """First-order geometric (Sampson) error of ``x2^T F x1 = 0`` (HZ eq. 11.9), per point.

    ``d = x2^T F x1 / sqrt((F x1)_1^2 + (F x1)_2^2 + (F^T x2)_1^2 + (F^T x2)_2^2)``, in the units of
    ``x1, x2`` (pixels for a fundamental matrix, normalized units for E). Absolute unless ``signed``.
    """
    F = np.asarray(F, float)
    h1 = np.c_[np.asarray(x1, float), np.ones(len(x1))]
    h2 = np.c_[np.asarray(x2, float), np.ones(len(x2))]
    Fx1 = h1 @ F.T
    Ftx2 = h2 @ F
    num = np.sum(h2 * Fx1, axis=1)
    den = np.sqrt(Fx1[:, 0] ** 2 + Fx1[:, 1] ** 2 + Ftx2[:, 0] ** 2 + Ftx2[:, 1] ** 2)
    d = num / np.maximum(den, 1e-300)
    return d if signed else np.abs(d)


def fundamental_from_essential(E: np.ndarray, K1: np.ndarray, K2: np.ndarray | None = None) -> np.ndarray:
    """``F = K2^-T E K1^-1`` (HZ eq. 9.12), scaled to unit Frobenius norm."""
    K1 = check_K(K1)
    K2 = K1 if K2 is None else check_K(K2)
    F = np.linalg.inv(K2).T @ np.asarray(E, float) @ np.linalg.inv(K1)
    nrm = np.linalg.norm(F)
    if not np.isfinite(nrm) or nrm == 0:
        raise GeometryError("fundamental_from_essential: E is zero or not finite")
    return F / nrm


def essential_from_fundamental(F: np.ndarray, K1: np.ndarray, K2: np.ndarray | None = None) -> np.ndarray:
    """``E = K2^T F K1`` projected onto the essential manifold."""
    K1 = check_K(K1)
    K2 = K1 if K2 is None else check_K(K2)
    return project_to_essential(K2.T @ np.asarray(F, float) @ K1)


def essential_from_pose(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """``E = [t]x R`` for ``X_2 = R X_1 + t``."""
    return hat(np.asarray(t, float).reshape(3)) @ np.asarray(R, float)


# ----------------------------------------------------------------------------- decomposition
def decompose_essential(E: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The two rotations and the unit translation of ``E = [t]x R`` (HZ result 9.19).

    With ``E = U diag(1, 1, 0) V^T`` (``det U = det V = 1``): ``R1 = U W V^T``, ``R2 = U W^T V^T``,
    ``t = u_3``; the four candidate poses are ``(R1, t), (R1, -t), (R2, t), (R2, -t)``.
    """
    E = np.asarray(E, float)
    if E.shape != (3, 3) or not np.all(np.isfinite(E)):
        raise GeometryError(f"decompose_essential needs a finite 3x3 matrix, got {E!r}")
    U, S, Vt = np.linalg.svd(E)
    if S[1] < 1e-9 * max(S[0], 1e-300):
        raise GeometryError(f"not an essential matrix: singular values {S}")
    if np.linalg.det(U) < 0:
        U = -U
    if np.linalg.det(Vt) < 0:
        Vt = -Vt
    return U @ _W @ Vt, U @ _W.T @ Vt, U[:, 2].copy()
