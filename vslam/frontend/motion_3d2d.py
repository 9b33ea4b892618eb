"""3D-2D motion: the camera pose from keypoints matched to map points, by pose-only robust
Gauss-Newton from the motion prediction (ORB-SLAM's TrackWithMotionModel) or PnP RANSAC
(:func:`vslam.geometry.pnp.pnp_ransac`), with, for stereo / RGB-D, the virtual right camera's
residual ``u_r = u - bf / z`` (ORB-SLAM2, Mur-Artal & Tardos 2017, eq. (2))."""
from __future__ import annotations

import numpy as np

from vslam.frontend.config import FrontendConfig
from vslam.geometry.pnp import pnp_ransac, refine_pose


def pose_3d2d(cfg: FrontendConfig, K: np.ndarray, bf: float, sensor: str, Xw: np.ndarray, uv: np.ndarray,
              sigma: np.ndarray, u_right: np.ndarray | None, T_cw_guess: np.ndarray | None,
              refine_only: bool = False, final: bool = True) -> tuple[np.ndarray | None, np.ndarray]:
    """``(T_cam_world or None, inlier mask over the N associations)``.

    ``refine_only``: only the robust optimization from ``T_cw_guess``; ``final=False``: a first
    pass whose pose only places a second association pass (no refinement with all residuals).
    """
    tr = cfg.tracking
    if T_cw_guess is not None and (refine_only or tr.pose_from_prediction):
        # matches were gated around the prediction: robust pose optimization straight from it
        # (ORB-SLAM's TrackWithMotionModel); RANSAC only when that explains too few matches
        T_cw, inl = refine_pose(T_cw_guess, Xw, uv, K, sigma, u_right, bf,
                                rounds=tr.refine_rounds_prediction if refine_only else tr.refine_rounds)
        if refine_only or inl.sum() >= max(tr.min_inliers, tr.prediction_min_inlier_ratio * len(Xw)):
            return T_cw, inl
    # with depth, a first-pass pose only places the second association pass (tracking.pnp_refine_rounds_first_pass)
    T_cw, m = pnp_ransac(Xw, uv, K, T_cw_guess, tr.pnp_reproj_px, tr.pnp_iterations,
                         refine_rounds=tr.pnp_refine_rounds_first_pass if not final and sensor != "mono"
                         else tr.pnp_refine_rounds)
    if T_cw is None:
        return None, np.zeros(len(Xw), bool)
    if not final:  # a refinement with all residuals follows the second association pass
        return T_cw, m
    return refine_pose(T_cw, Xw, uv, K, sigma, u_right, bf, rounds=tr.refine_rounds)
