"""SO(3), SE(3) and Sim(3) on 4x4 / 3x3 NumPy arrays.

Conventions: a pose ``T_a_b`` is a 4x4 matrix mapping points from frame ``b`` to frame ``a``
(``X_a = R X_b + t``); a similarity keeps the scale folded into the top-left block
(``S = [[s R, t], [0, 1]]``), so :func:`transform_points` and ``@`` work for both.
Tangent vectors are ordered ``xi = (rho, phi)`` (translation part first, then rotation), as in
Barfoot, "State Estimation for Robotics" (2017), sec. 7.1, and Sola et al., "A micro Lie theory
for state estimation in robotics" (arXiv:1812.01537), whose closed forms (Rodrigues, the left
Jacobian ``V``) are used below.

Example:
    >>> T = make_T(so3_exp(np.array([0.0, 0.0, np.pi / 2])), np.array([1.0, 0.0, 0.0]))
    >>> transform_points(T, np.array([[1.0, 0.0, 0.0]])).round(6)
    array([[1., 1., 0.]])
"""
from __future__ import annotations

import numpy as np

from vslam.errors import GeometryError

_EPS = 1e-10


def hat(w: np.ndarray) -> np.ndarray:
    """Skew-symmetric matrix ``[w]x`` of a ``(3,)`` vector, or ``(N, 3, 3)`` for ``(N, 3)``."""
    w = np.asarray(w, dtype=float)
    W = np.zeros(w.shape[:-1] + (3, 3))
    W[..., 0, 1], W[..., 0, 2] = -w[..., 2], w[..., 1]
    W[..., 1, 0], W[..., 1, 2] = w[..., 2], -w[..., 0]
    W[..., 2, 0], W[..., 2, 1] = -w[..., 1], w[..., 0]
    return W


def vee(W: np.ndarray) -> np.ndarray:
    """Inverse of :func:`hat`: ``(..., 3, 3)`` skew matrices -> ``(..., 3)`` vectors."""
    W = np.asarray(W, dtype=float)
    return np.stack([W[..., 2, 1], W[..., 0, 2], W[..., 1, 0]], axis=-1)


def so3_exp(w: np.ndarray) -> np.ndarray:
    """Rodrigues' formula ``R = I + sin(a)/a [w]x + (1 - cos a)/a^2 [w]x^2`` (Sola eq. 77).

    Accepts ``(3,)`` -> ``(3, 3)`` or ``(N, 3)`` -> ``(N, 3, 3)``.
    """
    w = np.asarray(w, dtype=float)
    a = np.linalg.norm(w, axis=-1)[..., None, None]
    W = hat(w)
    small = a < 1e-8
    a_safe = np.where(small, 1.0, a)
    A = np.where(small, 1.0 - a * a / 6.0, np.sin(a_safe) / a_safe)
    B = np.where(small, 0.5 - a * a / 24.0, (1.0 - np.cos(a_safe)) / (a_safe * a_safe))
    return np.eye(3) + A * W + B * (W @ W)


def so3_log(R: np.ndarray) -> np.ndarray:
    """Rotation vector ``w`` with ``so3_exp(w) = R`` (``|w| <= pi``), for ``(3, 3)`` or ``(N, 3, 3)``.

    Uses the quaternion route (angle from ``atan2(|v|, w)``), which is accurate near 0 and pi.
    """
    R = np.asarray(R, dtype=float)
    q = rotmat_to_quat(R)  # (..., 4) x y z w, w >= 0
    v = q[..., :3]
    s = np.linalg.norm(v, axis=-1)
    ang = 2.0 * np.arctan2(s, q[..., 3])
    small = s < 1e-12
    scale = np.where(small, 2.0 / np.where(np.abs(q[..., 3]) < _EPS, 1.0, q[..., 3]), ang / np.where(small, 1.0, s))
    return v * scale[..., None]


def _left_jacobian_so3(w: np.ndarray) -> np.ndarray:
    """``V = I + (1 - cos a)/a^2 [w]x + (a - sin a)/a^3 [w]x^2`` (Sola eq. 145)."""
    a = float(np.linalg.norm(w))
    W = hat(w)
    if a < 1e-8:
        return np.eye(3) + 0.5 * W + (W @ W) / 6.0
    return np.eye(3) + (1 - np.cos(a)) / a**2 * W + (a - np.sin(a)) / a**3 * (W @ W)


def se3_exp(xi: np.ndarray) -> np.ndarray:
    """``exp`` of ``xi = (rho, phi)`` in se(3): ``R = exp(phi)``, ``t = V(phi) rho`` (Sola eq. 172)."""
    xi = np.asarray(xi, dtype=float).reshape(6)
    rho, phi = xi[:3], xi[3:]
    return make_T(so3_exp(phi), _left_jacobian_so3(phi) @ rho)


def se3_log(T: np.ndarray) -> np.ndarray:
    """Inverse of :func:`se3_exp`: a 4x4 rigid transform -> ``(rho, phi)`` ``(6,)``."""
    T = np.asarray(T, dtype=float)
    phi = so3_log(T[:3, :3])
    rho = np.linalg.solve(_left_jacobian_so3(phi), T[:3, 3])
    return np.concatenate([rho, phi])


def make_T(R: np.ndarray, t: np.ndarray, s: float = 1.0) -> np.ndarray:
    """The 4x4 matrix ``[[s R, t], [0, 1]]`` (``s = 1``: SE(3); otherwise Sim(3))."""
    T = np.eye(4)
    T[:3, :3] = s * np.asarray(R, dtype=float)
    T[:3, 3] = np.asarray(t, dtype=float).reshape(3)
    return T


def make_sim3(s: float, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Sim(3) element ``[[s R, t], [0, 1]]`` (maps ``X -> s R X + t``)."""
    return make_T(R, t, s)


def sim3_decompose(S: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Split ``[[s R, t], [0, 1]]`` into ``(s, R, t)`` (``s = det(sR)^(1/3)``)."""
    S = np.asarray(S, dtype=float)
    sR = S[:3, :3]
    s = float(np.cbrt(np.linalg.det(sR)))
    if not np.isfinite(s) or s <= 0:
        raise GeometryError(f"not a similarity transform: det of the 3x3 block is {np.linalg.det(sR)}")
    return s, sR / s, S[:3, 3].copy()


def inv_T(T: np.ndarray) -> np.ndarray:
    """Inverse of a Sim(3) 4x4 (``(N, 4, 4)`` batches too): ``[[A^-1, -A^-1 t], [0, 1]]``.

    ``(sR)^-1 = R^T / s``, computed as ``A^T / s^2``; rigid transforms take :func:`inv_se3` (no scale).
    """
    T = np.asarray(T, dtype=float)
    A = T[..., :3, :3]
    s2 = np.cbrt(np.linalg.det(A)) ** 2
    Ainv = np.swapaxes(A, -1, -2) / s2[..., None, None]
    out = np.zeros_like(T)
    out[..., :3, :3] = Ainv
    out[..., :3, 3] = -(Ainv @ T[..., :3, 3, None])[..., 0]
    out[..., 3, 3] = 1.0
    return out


def inv_se3(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid 4x4 ``[[R, t], [0, 1]]`` (or a ``(..., 4, 4)`` batch): ``[[R^T, -R^T t], [0, 1]]``.

    The fast form for SE(3) (no Sim(3) scale); one 4x4 takes the per-frame path. :func:`inv_T`
    also inverts Sim(3).
    """
    T = np.asarray(T, dtype=float)
    if T.ndim == 2:
        out = np.eye(4)
        out[:3, :3] = T[:3, :3].T
        out[:3, 3] = -T[:3, :3].T @ T[:3, 3]
        return out
    R_t = np.swapaxes(T[..., :3, :3], -1, -2)
    out = np.zeros_like(T)
    out[..., :3, :3] = R_t
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", R_t, T[..., :3, 3])
    out[..., 3, 3] = 1.0
    return out


def compose(*Ts: np.ndarray) -> np.ndarray:
    """Product ``T_1 @ T_2 @ ...`` (``compose(T_a_b, T_b_c) = T_a_c``)."""
    if not Ts:
        return np.eye(4)
    out = np.asarray(Ts[0], dtype=float)
    for T in Ts[1:]:
        out = out @ np.asarray(T, dtype=float)
    return out


def relative_T(T_world_a: np.ndarray, T_world_b: np.ndarray) -> np.ndarray:
    """``T_a_b = T_world_a^-1 T_world_b`` (the motion from ``a`` to ``b`` in ``a``'s frame)."""
    return inv_T(T_world_a) @ np.asarray(T_world_b, dtype=float)


def transform_points(T: np.ndarray, X: np.ndarray) -> np.ndarray:
    """Apply a 4x4 SE(3)/Sim(3) ``T`` to ``(N, 3)`` points: ``A X + t``."""
    T = np.asarray(T, dtype=float)
    X = np.asarray(X, dtype=float)
    return X @ T[:3, :3].T + T[:3, 3]


def rotation_angle_deg(R: np.ndarray) -> np.ndarray | float:
    """Geodesic angle of a rotation (``(3, 3)`` or a 4x4 pose; batches ``(N, ...)`` too), degrees.

    ``angle = atan2(|vee(R - R^T)| / 2, (trace R - 1) / 2)``, accurate for tiny and large angles.
    """
    R = np.asarray(R, dtype=float)[..., :3, :3]
    c = (np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0
    s = np.linalg.norm(vee(R - np.swapaxes(R, -1, -2)), axis=-1) / 2.0
    ang = np.degrees(np.arctan2(s, c))
    return float(ang) if np.ndim(ang) == 0 else ang


def rotation_error_deg(R_a: np.ndarray, R_b: np.ndarray) -> float:
    """Angle of ``R_a^T R_b`` in degrees (accepts 3x3 rotations or 4x4 poses)."""
    Ra = np.asarray(R_a, dtype=float)[:3, :3]
    Rb = np.asarray(R_b, dtype=float)[:3, :3]
    return float(rotation_angle_deg(Ra.T @ Rb))


def angle_between_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray | float:
    """Angle between vectors (``(3,)`` or ``(N, 3)`` row-wise), degrees, via ``atan2(|a x b|, a.b)``."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    ang = np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1)))
    return float(ang) if np.ndim(ang) == 0 else ang


def project_to_so3(M: np.ndarray) -> np.ndarray:
    """Nearest rotation to a 3x3 matrix in the Frobenius norm: ``U diag(1, 1, det(U V^T)) V^T``."""
    U, _, Vt = np.linalg.svd(np.asarray(M, dtype=float))
    D = np.eye(3)
    D[2, 2] = np.sign(np.linalg.det(U @ Vt)) or 1.0
    return U @ D @ Vt


def is_rotation(R: np.ndarray, tol: float = 1e-6) -> bool:
    """True when ``R^T R = I`` and ``det R = 1`` within ``tol``."""
    R = np.asarray(R, dtype=float)
    return bool(
        R.shape == (3, 3) and np.all(np.isfinite(R))
        and np.allclose(R.T @ R, np.eye(3), atol=tol) and abs(np.linalg.det(R) - 1.0) < tol
    )


def quat_to_rotmat(q_xyzw: np.ndarray) -> np.ndarray:
    """Unit quaternion(s) ``(x, y, z, w)`` (TUM / Hamilton order) -> rotation matrix (normalises first)."""
    q = np.asarray(q_xyzw, dtype=float)
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    if np.any(n < _EPS) or not np.all(np.isfinite(q)):
        raise GeometryError("quaternion has zero norm or NaN/inf components")
    x, y, z, w = np.moveaxis(q / n, -1, 0)
    R = np.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w),
        2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
        2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y),
    ], axis=-1)
    return R.reshape(q.shape[:-1] + (3, 3))


def rotmat_to_quat(R: np.ndarray) -> np.ndarray:
    """Rotation matrix(ces) -> unit quaternion(s) ``(x, y, z, w)`` with ``w >= 0``.

    Shepperd's method (branch on the largest diagonal term), vectorized.
    """
    R = np.asarray(R, dtype=float)
    shp = R.shape[:-2]
    R = R.reshape(-1, 3, 3)
    tr = np.trace(R, axis1=1, axis2=2)
    d = np.stack([R[:, 0, 0], R[:, 1, 1], R[:, 2, 2], tr], axis=1)
    k = np.argmax(d, axis=1)
    q = np.empty((R.shape[0], 4))
    # case w largest
    m = k == 3
    if np.any(m):
        r = R[m]
        s = np.sqrt(1.0 + tr[m]) * 2.0
        q[m] = np.stack([(r[:, 2, 1] - r[:, 1, 2]) / s, (r[:, 0, 2] - r[:, 2, 0]) / s,
                         (r[:, 1, 0] - r[:, 0, 1]) / s, 0.25 * s], axis=1)
    for i in range(3):
        m = k == i
        if not np.any(m):
            continue
        j, l = (i + 1) % 3, (i + 2) % 3
        r = R[m]
        s = np.sqrt(np.maximum(1.0 + r[:, i, i] - r[:, j, j] - r[:, l, l], 0.0)) * 2.0
        qi = np.empty((r.shape[0], 4))
        qi[:, i] = 0.25 * s
        qi[:, j] = (r[:, j, i] + r[:, i, j]) / s
        qi[:, l] = (r[:, l, i] + r[:, i, l]) / s
        qi[:, 3] = (r[:, l, j] - r[:, j, l]) / s
        q[m] = qi
    q *= np.where(q[:, 3:4] < 0, -1.0, 1.0)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return q.reshape(shp + (4,))


def slerp_rotation(R0: np.ndarray, R1: np.ndarray, alpha: float | np.ndarray) -> np.ndarray:
    """Spherical linear interpolation ``R0 exp(alpha log(R0^T R1))`` (Shoemake 1985): the one
    rotation interpolation (trajectories, ground truth at image times, frame corrections).

    One pair ``(3, 3)`` with ``alpha`` a scalar (-> ``(3, 3)``) or ``(M,)`` (-> ``(M, 3, 3)``), or
    ``M`` pairs ``(M, 3, 3)`` with ``alpha (M,)``.
    """
    R0 = np.asarray(R0, dtype=float)
    w = so3_log(np.swapaxes(R0, -1, -2) @ np.asarray(R1, dtype=float))
    a = np.asarray(alpha, dtype=float)
    return R0 @ so3_exp(a[..., None] * w)


def interpolate_pose(T0: np.ndarray, T1: np.ndarray, alpha: float | np.ndarray) -> np.ndarray:
    """Pose between ``T0`` (``alpha=0``) and ``T1`` (``alpha=1``): SLERP rotation, linear translation.

    Both are ``T_world_cam``-style 4x4 rigid transforms; ``alpha`` scalar or ``(M,)``.
    """
    T0 = np.asarray(T0, dtype=float)
    T1 = np.asarray(T1, dtype=float)
    a = np.asarray(alpha, dtype=float)
    R = slerp_rotation(T0[:3, :3], T1[:3, :3], a)
    t = (1.0 - a)[..., None] * T0[:3, 3] + a[..., None] * T1[:3, 3]
    out = np.zeros(a.shape + (4, 4))
    out[..., :3, :3] = R
    out[..., :3, 3] = t
    out[..., 3, 3] = 1.0
    return out


def interpolate_trajectory(
    timestamps: np.ndarray, T_world_cam: np.ndarray, query_times: np.ndarray
) -> np.ndarray:
    """Poses at ``query_times`` from a sorted trajectory ``(N,)``, ``(N, 4, 4)`` by per-segment SLERP.

    Query times outside ``[t_0, t_N-1]`` raise :class:`GeometryError` (no extrapolation).
    """
    ts = np.asarray(timestamps, dtype=float)
    Ts = np.asarray(T_world_cam, dtype=float)
    q = np.atleast_1d(np.asarray(query_times, dtype=float))
    if len(ts) < 2 or np.any(np.diff(ts) <= 0):
        raise GeometryError("interpolate_trajectory needs >= 2 strictly increasing timestamps")
    if np.any(q < ts[0]) or np.any(q > ts[-1]):
        raise GeometryError(f"query times outside the trajectory span [{ts[0]}, {ts[-1]}]")
    i = np.clip(np.searchsorted(ts, q, side="right") - 1, 0, len(ts) - 2)
    a = (q - ts[i]) / (ts[i + 1] - ts[i])
    out = np.zeros((len(q), 4, 4))
    out[:, :3, :3] = slerp_rotation(Ts[i, :3, :3], Ts[i + 1, :3, :3], a)
    out[:, :3, 3] = (1 - a)[:, None] * Ts[i, :3, 3] + a[:, None] * Ts[i + 1, :3, 3]
    out[:, 3, 3] = 1.0
    return out
