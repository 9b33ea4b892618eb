"""Levenberg-Marquardt refinement of an essential matrix on the pixel Sampson error (5-dof manifold)."""
from __future__ import annotations

import numpy as np

from vslam.geometry.essential import check_K, decompose_essential, project_to_essential, sampson_distance
from vslam.geometry.lie import hat, so3_exp


def _tangent_basis(t: np.ndarray) -> np.ndarray:
    """A 3x2 orthonormal basis of the plane orthogonal to the unit vector ``t``."""
    x, y, z = t
    b1 = np.array([0.0, -z, y]) if abs(x) < 0.9 else np.array([z, 0.0, -x])  # t x e_1 or e_2 x t
    b1 /= np.linalg.norm(b1)
    b2 = np.array([y * b1[2] - z * b1[1], z * b1[0] - x * b1[2], x * b1[1] - y * b1[0]])
    return np.stack([b1, b2], axis=1)


def _sampson_and_jacobian(
    F: np.ndarray, dF: np.ndarray, h1: np.ndarray, h2: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Signed Sampson residuals ``r = n / d`` and their derivatives along the directions ``dF (P, 3, 3)``.

    ``n = h2^T F h1``, ``d^2 = (F h1)_1^2 + (F h1)_2^2 + (F^T h2)_1^2 + (F^T h2)_2^2``;
    ``dr = dn / d - n dd / d^2`` with ``dd = (Fh1 . dFh1 + F^Th2 . dF^Th2) / d`` over the first two rows.
    """
    Fx1 = h1 @ F.T
    Ftx2 = h2 @ F
    num = np.sum(h2 * Fx1, axis=1)
    den = np.sqrt(Fx1[:, 0] ** 2 + Fx1[:, 1] ** 2 + Ftx2[:, 0] ** 2 + Ftx2[:, 1] ** 2)
    den = np.maximum(den, 1e-300)
    dFx1 = h1 @ np.swapaxes(dF, 1, 2)  # (P, N, 3): rows dF h1
    dFtx2 = h2 @ dF  # (P, N, 3): rows dF^T h2
    dnum = np.sum(h2[None] * dFx1, axis=2)
    dden = (Fx1[None, :, 0] * dFx1[..., 0] + Fx1[None, :, 1] * dFx1[..., 1]
            + Ftx2[None, :, 0] * dFtx2[..., 0] + Ftx2[None, :, 1] * dFtx2[..., 1]) / den
    r = num / den
    J = (dnum / den - num * dden / den**2).T  # (N, P)
    return r, J


def refine_essential(
    E: np.ndarray, x1: np.ndarray, x2: np.ndarray, K: np.ndarray,
    iterations: int = 10, huber_px: float | None = 2.0,
) -> np.ndarray:
    """Levenberg-Marquardt on the pixel Sampson error over the 5-dof essential manifold.

    ``E = [t]x R`` with ``R <- exp(dw) R`` and ``t <- normalize(t + B db)`` (``B`` spans the tangent
    of the unit sphere at ``t``); residuals are the signed Sampson distances of
    ``F = K^-T E K^-1`` in pixels (HZ eq. 11.9), Huber-weighted (IRLS) when ``huber_px`` is set.
    The Jacobian is analytic: ``dE/dw_k = [t]x [e_k]x R`` and ``dE/db_j = [B_j]x R``.
    """
    K = check_K(K)
    Kinv = np.linalg.inv(K)
    R, _, t = decompose_essential(E)
    h1 = np.c_[np.asarray(x1, float), np.ones(len(x1))]
    h2 = np.c_[np.asarray(x2, float), np.ones(len(x2))]
    eye_hat = hat(np.eye(3))  # [e_k]x, (3, 3, 3)

    def model(R_: np.ndarray, t_: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        B = _tangent_basis(t_)
        tx = hat(t_)
        dE = np.concatenate([tx @ eye_hat @ R_, hat(B.T) @ R_], axis=0)  # (5, 3, 3)
        return Kinv.T @ tx @ R_ @ Kinv, Kinv.T @ dE @ Kinv

    def resid(R_: np.ndarray, t_: np.ndarray) -> np.ndarray:
        return sampson_distance(Kinv.T @ hat(t_) @ R_ @ Kinv, h1[:, :2], h2[:, :2], signed=True)

    lam = 1e-3
    for _ in range(iterations):
        F, dF = model(R, t)
        r, J = _sampson_and_jacobian(F, dF, h1, h2)
        w = np.ones_like(r)
        if huber_px is not None:
            a = np.abs(r)
            w = np.where(a <= huber_px, 1.0, huber_px / np.maximum(a, 1e-300))
        H = J.T @ (w[:, None] * J)
        g = J.T @ (w * r)
        cost = np.sum(w * r * r)
        improved = converged = False
        B = _tangent_basis(t)
        for _ in range(6):
            step = -np.linalg.solve(H + lam * np.diag(np.diag(H) + 1e-12), g)
            Rn = so3_exp(step[:3]) @ R
            tn = t + B @ step[3:]
            tn /= np.linalg.norm(tn)
            rn = resid(Rn, tn)
            new_cost = np.sum(w * rn * rn)
            if new_cost < cost:
                converged = cost - new_cost < 1e-6 * cost
                R, t = Rn, tn
                lam = max(lam / 10, 1e-9)
                improved = True
                break
            lam *= 10
        if not improved or converged or np.linalg.norm(step) < 1e-10:
            break
    return project_to_essential(hat(t) @ R)
