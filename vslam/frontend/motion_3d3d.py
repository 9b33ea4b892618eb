"""3D-3D motion: the camera pose from keypoint depths aligned onto their map points
(RANSAC + Umeyama, :func:`vslam.geometry.align.align_points`)."""
from __future__ import annotations

import numpy as np

from vslam.frontend.config import FrontendConfig
from vslam.errors import GeometryError
from vslam.geometry.align import align_points
from vslam.geometry.camera import PinholeCamera
from vslam.geometry.lie import inv_se3


def pose_3d3d(cfg: FrontendConfig, camera: PinholeCamera, sensor: str, bf: float, Xw: np.ndarray, uv: np.ndarray,
              z: np.ndarray, rng: np.random.Generator, refine_only: bool = False) -> tuple[np.ndarray | None, np.ndarray]:
    """``(T_cam_world or None, inlier mask over the N associations)`` from map points ``Xw (N, 3)``
    and their keypoints ``uv (N, 2)`` (undistorted) with depths ``z (N,)`` (NaN: no depth, not used).
    The inlier threshold grows with depth: with the disparity noise for stereo
    (``dz = z^2 / bf * d_disp``), quadratically for RGB-D (Khoshelham & Elberink 2012)."""
    tr = cfg.tracking
    has = np.isfinite(z)
    inl = np.zeros(len(z), bool)
    if has.sum() < tr.min_inliers:
        return None, inl
    Xc = camera.backproject(uv[has], z[has])
    if sensor == "stereo":
        thr = np.maximum(tr.align_inlier_m, tr.align_stereo_disparity_px * z[has] ** 2 / bf)
    else:
        thr = tr.align_inlier_m * np.maximum(1.0, z[has] ** 2)
    try:
        T_wc, m = align_points(Xc, Xw[has], threshold=thr,
                               max_iters=tr.align_iterations if not refine_only else tr.align_refine_iterations, seed=rng)
    except GeometryError:
        return None, inl
    if m.sum() < tr.min_inliers:
        return None, inl
    inl[np.flatnonzero(has)[m]] = True
    return inv_se3(T_wc), inl
