"""Two-view and rectified-stereo triangulation, and the per-point checks used to reject bad points.

Triangulation is the linear (homogeneous) DLT of Hartley & Zisserman, "Multiple View Geometry"
2nd ed., sec. 12.2 (``A X = 0`` with rows ``x p3^T - p1^T``, ``y p3^T - p2^T`` per view, solved by
SVD), batched over all points by OpenCV's ``triangulatePoints``. Rectified stereo uses
``z = fx b / d`` with disparity ``d = u_left - u_right`` (HZ sec. 9.1 / any stereo text).

Failure contract: :func:`triangulate` and :func:`triangulate_stereo` raise
:class:`vslam.errors.GeometryError` on bad shapes, NaN/inf input or a zero baseline. Points that
cannot be triangulated (parallel rays, non-positive disparity) come back as ``inf``/``nan`` rows
instead of raising; use :func:`good_triangulation_mask` to reject them.
"""
from __future__ import annotations

import cv2
import numpy as np

from vslam.errors import GeometryError
from vslam.geometry.lie import angle_between_deg


def _check_pose(T: np.ndarray, name: str) -> np.ndarray:
    T = np.asarray(T, dtype=float)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise GeometryError(f"{name} must be a finite 4x4 pose, got shape {T.shape}")
    return T


def _check_K(K: np.ndarray) -> np.ndarray:
    K = np.asarray(K, dtype=float)
    if K.shape != (3, 3) or not np.all(np.isfinite(K)):
        raise GeometryError(f"K must be a finite 3x3 matrix, got {K!r}")
    return K


def camera_center(T_cam_world: np.ndarray) -> np.ndarray:
    """Camera centre in the world frame, ``C = -R^T t``."""
    T = np.asarray(T_cam_world, dtype=float)
    return -T[:3, :3].T @ T[:3, 3]


def triangulate(
    T_cam1_world: np.ndarray, T_cam2_world: np.ndarray, K: np.ndarray,
    x1: np.ndarray, x2: np.ndarray, K2: np.ndarray | None = None,
) -> np.ndarray:
    """World points ``(N, 3)`` from undistorted pixels seen by two posed cameras (linear DLT).

    Each point solves ``A X = 0`` (HZ eq. 12.1, rows ``x p3^T - p1^T``, ``y p3^T - p2^T`` per view)
    for the homogeneous ``X`` by SVD (HZ sec. 12.2, the homogeneous method; OpenCV's
    ``triangulatePoints`` on the pixel projections ``P = K [R | t]``), then ``X[:3] / X[3]``.
    The one triangulation of the package: the monocular initializer, new monocular points, the
    2d2d scale and the re-triangulation after a monocular BA all use it. (The inhomogeneous
    variant, ``X[3] = 1``, was dropped: KITTI 07 mono ATE +3.2 % with it everywhere.)
    Rays that are parallel (zero baseline or a point at infinity) give huge or non-finite
    coordinates; the callers' parallax / depth checks reject them.

    Args:
        T_cam1_world, T_cam2_world: 4x4 poses (world -> camera). K: 3x3 intrinsics of camera 1
        (and camera 2 unless ``K2`` is given). x1, x2: ``(N, 2)`` undistorted pixels.

    Returns:
        ``X_world (N, 3)``.

    Raises:
        GeometryError: shape mismatch or NaN/inf input.
    """
    T1 = _check_pose(T_cam1_world, "T_cam1_world")
    T2 = _check_pose(T_cam2_world, "T_cam2_world")
    x1 = np.asarray(x1, dtype=np.float64)
    x2 = np.asarray(x2, dtype=np.float64)
    if x1.ndim != 2 or x1.shape[1] != 2 or x1.shape != x2.shape:
        raise GeometryError(f"triangulate needs two (N, 2) pixel arrays of equal shape, got {x1.shape} and {x2.shape}")
    if not (np.all(np.isfinite(x1)) and np.all(np.isfinite(x2))):
        raise GeometryError("triangulate got NaN or inf pixels; drop those correspondences first")
    if len(x1) == 0:
        return np.zeros((0, 3))
    K1 = _check_K(K)
    K2 = K1 if K2 is None else _check_K(K2)
    Xh = cv2.triangulatePoints(K1 @ T1[:3], K2 @ T2[:3], x1.T, x2.T)
    with np.errstate(divide="ignore", invalid="ignore"):
        return (Xh[:3] / Xh[3]).T


def parallax_deg(T_cam1_world: np.ndarray, T_cam2_world: np.ndarray, X_world: np.ndarray) -> np.ndarray:
    """Angle at each point between the rays to the two camera centres, degrees ``(N,)``."""
    X = np.asarray(X_world, dtype=float)
    return np.asarray(angle_between_deg(X - camera_center(T_cam1_world), X - camera_center(T_cam2_world)))


def reprojection_error(
    T_cam_world: np.ndarray, K: np.ndarray, X_world: np.ndarray, x: np.ndarray
) -> np.ndarray:
    """Pixel distance between ``x (N, 2)`` and the projection of ``X_world``; ``inf`` behind the camera."""
    T = np.asarray(T_cam_world, dtype=float)
    K = np.asarray(K, dtype=float)
    Xc = np.asarray(X_world, dtype=float) @ T[:3, :3].T + T[:3, 3]
    z = Xc[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = K[0, 0] * Xc[:, 0] / z + K[0, 1] * Xc[:, 1] / z + K[0, 2]
        v = K[1, 1] * Xc[:, 1] / z + K[1, 2]
        err = np.hypot(u - x[:, 0], v - x[:, 1])
    return np.where((z > 0) & np.isfinite(err), err, np.inf)


def cheirality_mask(T_cam_world: np.ndarray, X_world: np.ndarray, min_depth: float = 0.0) -> np.ndarray:
    """True where the point is finite and in front of the camera (``z_cam > min_depth``)."""
    T = np.asarray(T_cam_world, dtype=float)
    X = np.asarray(X_world, dtype=float)
    z = X @ T[2, :3] + T[2, 3]
    return np.all(np.isfinite(X), axis=1) & (z > min_depth)


def good_triangulation_mask(
    T_cam1_world: np.ndarray, T_cam2_world: np.ndarray, K: np.ndarray,
    x1: np.ndarray, x2: np.ndarray, X_world: np.ndarray,
    max_reproj_px: float = 2.0, min_parallax_deg: float = 1.0, min_depth: float = 0.0,
) -> np.ndarray:
    """Points worth keeping: in front of both cameras, reprojecting within ``max_reproj_px`` in both
    views, and seen with at least ``min_parallax_deg`` of parallax (ORB-SLAM's checks, Mur-Artal 2015)."""
    return (
        cheirality_mask(T_cam1_world, X_world, min_depth) & cheirality_mask(T_cam2_world, X_world, min_depth)
        & (reprojection_error(T_cam1_world, K, X_world, x1) < max_reproj_px)
        & (reprojection_error(T_cam2_world, K, X_world, x2) < max_reproj_px)
        & (parallax_deg(T_cam1_world, T_cam2_world, X_world) >= min_parallax_deg)
    )


# ----------------------------------------------------------------------------- rectified stereo
def disparity_to_depth(disparity: np.ndarray, fx: float, baseline: float) -> np.ndarray:
    """``z = fx b / d``; non-positive or non-finite disparities give ``nan``."""
    d = np.asarray(disparity, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(d > 0, fx * baseline / d, np.nan)


def depth_to_disparity(depth: np.ndarray, fx: float, baseline: float) -> np.ndarray:
    """``d = fx b / z``; non-positive or non-finite depths give ``nan``."""
    z = np.asarray(depth, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(z > 0, fx * baseline / z, np.nan)


def triangulate_stereo(uv_left: np.ndarray, u_right: np.ndarray, K: np.ndarray, baseline: float) -> np.ndarray:
    """Left-camera points ``(N, 3)`` from a rectified pair: ``z = fx b / (u_l - u_r)``, then back-projection.

    The right camera sits at ``+baseline`` along the left x axis (``u_right = u_left - fx b / z``).
    Rows with non-positive disparity are ``nan``.

    Raises:
        GeometryError: non-positive baseline or mismatched shapes.
    """
    K = np.asarray(K, dtype=float)
    uv = np.asarray(uv_left, dtype=float)
    ur = np.asarray(u_right, dtype=float).reshape(-1)
    if not (np.isfinite(baseline) and baseline > 0):
        raise GeometryError(f"triangulate_stereo: the baseline must be positive, got {baseline}")
    if uv.ndim != 2 or uv.shape[1] != 2 or ur.shape[0] != uv.shape[0]:
        raise GeometryError(f"triangulate_stereo needs (N, 2) left pixels and (N,) right u, got {uv.shape}, {ur.shape}")
    z = disparity_to_depth(uv[:, 0] - ur, K[0, 0], baseline)
    y = (uv[:, 1] - K[1, 2]) / K[1, 1]
    x = (uv[:, 0] - K[0, 2] - K[0, 1] * y) / K[0, 0]
    return np.stack([x * z, y * z, z], axis=1)


def project_stereo(X_cam: np.ndarray, K: np.ndarray, baseline: float) -> np.ndarray:
    """``(u_left, v, u_right)`` ``(N, 3)`` of left-camera points in a rectified rig."""
    X = np.asarray(X_cam, dtype=float)
    K = np.asarray(K, dtype=float)
    z = X[:, 2]
    u = K[0, 0] * X[:, 0] / z + K[0, 1] * X[:, 1] / z + K[0, 2]
    v = K[1, 1] * X[:, 1] / z + K[1, 2]
    return np.stack([u, v, u - K[0, 0] * baseline / z], axis=1)


# ----------------------------------------------------------------------------- tracking checks
def reprojection_error_depth(T_cam_world: np.ndarray, K: np.ndarray, X_world: np.ndarray, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(pixel error (N,), depth (N,))`` of world points in a camera."""
    Xc = X_world @ T_cam_world[:3, :3].T + T_cam_world[:3, 3]
    z = Xc[:, 2]
    zs = np.where(np.abs(z) < 1e-9, 1e-9, z)
    u = K[0, 0] * Xc[:, 0] / zs + K[0, 2]
    v = K[1, 1] * Xc[:, 1] / zs + K[1, 2]
    return np.hypot(u - uv[:, 0], v - uv[:, 1]), z


def ray_parallax_deg(T_world_cam1: np.ndarray, T_world_cam2: np.ndarray, X_world: np.ndarray) -> np.ndarray:
    """Angle at each point between the rays to the two camera centres."""
    a = X_world - T_world_cam1[:3, 3]
    b = X_world - T_world_cam2[:3, 3]
    c = np.einsum("ij,ij->i", a, b) / np.maximum(np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1), 1e-12)
    return np.degrees(np.arccos(np.clip(c, -1, 1)))
