"""vslam.eval: trajectory I/O, association, alignment, ATE/RPE/KITTI metrics and plots."""
from vslam.eval.associate import associate_trajectories
from vslam.eval.evaluate import EvalConfig, EvalResult, evaluate_files, evaluate_trajectories
from vslam.eval.kitti_metric import KittiResult, kitti_odometry_error
from vslam.eval.metrics import Alignment, ErrorStats, align, ate_errors, rpe_errors, rpe_pairs
from vslam.trajectory import Trajectory, associate_timestamps, read_trajectory, write_trajectory

__all__ = [
    "Alignment", "ErrorStats", "EvalConfig", "EvalResult", "KittiResult", "Trajectory", "align",
    "associate_timestamps", "associate_trajectories", "ate_errors", "evaluate_files", "evaluate_trajectories",
    "kitti_odometry_error", "read_trajectory", "rpe_errors", "rpe_pairs", "write_trajectory",
]
