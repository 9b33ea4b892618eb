"""vslam.backend: windowed/global bundle adjustment, SE(3)/Sim(3) pose graphs, an EKF filter backend.

Everything takes and returns NumPy arrays (poses ``T_world_cam (K, 4, 4)``, points ``(P, 3)``), so
callers never see GTSAM. GTSAM is imported lazily by the functions that use it.
"""
from vslam.backend.bundle_adjustment import global_bundle_adjustment, local_bundle_adjustment
from vslam.backend.config import EKFConfig, GlobalBAConfig, LocalBAConfig, PoseGraphConfig
from vslam.backend.drift_demo import run_drift_demo
from vslam.backend.ekf import EKFState, PoseEKF, pose_covariance_from_inliers
from vslam.map.pose_graph import PoseGraphResult, correct_points, optimize_pose_graph
from vslam.backend.problem import BAProblem, BAResult

__all__ = [
    "BAProblem", "BAResult", "EKFConfig", "EKFState", "GlobalBAConfig", "LocalBAConfig", "PoseEKF",
    "PoseGraphConfig", "PoseGraphResult", "correct_points", "global_bundle_adjustment", "local_bundle_adjustment",
    "optimize_pose_graph", "pose_covariance_from_inliers", "run_drift_demo",
]
