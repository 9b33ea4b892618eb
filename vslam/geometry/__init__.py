"""Pure geometry on NumPy arrays: no state, no I/O, imports nothing else of vslam except errors.

Conventions: poses are 4x4 ``T_a_b`` (maps points from frame ``b`` to ``a``); pixels ``(N, 2)``;
points ``(N, 3)``; two-view relative pose ``(R, t)`` means ``X_2 = R X_1 + t`` (``T_cam2_cam1``).
Failures raise :class:`vslam.errors.GeometryError` (no function returns ``None``); per-point
problems (a ray pair that cannot be triangulated) are reported as ``nan``/``inf`` or by masks.
"""
from __future__ import annotations

from vslam.geometry.align import align_points, umeyama_batch
from vslam.geometry.camera import PinholeCamera
from vslam.geometry.epipolar import (
    bearings,
    decompose_essential,
    epipolar_residual,
    essential_8point,
    essential_from_fundamental,
    essential_from_pose,
    estimate_essential,
    fundamental_from_essential,
    motion_parallax,
    normalize_points,
    project_to_essential,
    recover_pose,
    refine_essential,
    relative_pose,
    rotation_only_fit,
    sampson_distance,
    two_view_depths,
)
from vslam.geometry.lie import (
    angle_between_deg,
    compose,
    hat,
    interpolate_pose,
    interpolate_trajectory,
    inv_T,
    inv_se3,
    is_rotation,
    make_sim3,
    make_T,
    project_to_so3,
    quat_to_rotmat,
    relative_T,
    rotation_angle_deg,
    rotation_error_deg,
    rotmat_to_quat,
    se3_exp,
    se3_log,
    sim3_decompose,
    slerp_rotation,
    so3_exp,
    so3_log,
    transform_points,
    vee,
)
from vslam.geometry.pnp import project_points, reprojection_errors, solve_pnp
from vslam.geometry.scale import relative_scale
from vslam.geometry.triangulation import (
    camera_center,
    cheirality_mask,
    depth_to_disparity,
    disparity_to_depth,
    good_triangulation_mask,
    parallax_deg,
    project_stereo,
    reprojection_error,
    triangulate,
    triangulate_stereo,
)
from vslam.geometry.umeyama import umeyama

__all__ = [
    "PinholeCamera", "align_points", "angle_between_deg", "bearings", "camera_center", "cheirality_mask",
    "compose", "decompose_essential", "depth_to_disparity", "disparity_to_depth", "epipolar_residual",
    "essential_8point", "essential_from_fundamental", "essential_from_pose", "estimate_essential",
    "fundamental_from_essential", "good_triangulation_mask", "hat", "interpolate_pose",
    "interpolate_trajectory", "inv_T", "inv_se3", "is_rotation", "make_T", "make_sim3", "motion_parallax", "normalize_points",
    "parallax_deg", "project_points", "project_stereo", "project_to_essential", "project_to_so3",
    "quat_to_rotmat", "recover_pose", "refine_essential", "relative_T", "relative_pose", "relative_scale",
    "reprojection_error", "reprojection_errors", "rotation_angle_deg", "rotation_error_deg",
    "rotation_only_fit", "rotmat_to_quat", "sampson_distance", "se3_exp", "se3_log",
    "sim3_decompose", "slerp_rotation", "so3_exp", "so3_log", "solve_pnp",
    "transform_points", "triangulate", "triangulate_stereo", "two_view_depths", "umeyama", "umeyama_batch",
    "vee",
]
