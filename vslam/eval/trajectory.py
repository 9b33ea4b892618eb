"""Compatibility alias: the trajectory type and its file formats live in :mod:`vslam.trajectory`
(one layer below ``eval``, so the dataset readers can use it)."""
from vslam.trajectory import (  # noqa: F401
    Trajectory, detect_format, format_tum_line, poses_from_tum_rows, read_euroc, read_kitti, read_trajectory,
    read_tum, tum_rows_from_poses, write_euroc, write_kitti, write_trajectory, write_tum,
)
