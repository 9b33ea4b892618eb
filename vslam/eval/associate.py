"""Timestamp association of an estimated and a ground-truth trajectory: pairs within
``max_diff`` seconds (after adding ``offset`` to the estimate's timestamps), one-to-one, by
:func:`vslam.trajectory.associate_timestamps` (TUM's ``associate.py``, the same pairs as evo's
``sync.matching_time_indices`` when no pose is the nearest of two).
"""
from __future__ import annotations

from vslam.errors import TrajectoryError
from vslam.trajectory import Trajectory, associate_timestamps


def associate_trajectories(
    est: Trajectory,
    gt: Trajectory,
    max_diff: float = 0.01,
    offset: float = 0.0,
    by_index: bool = False,
    est_name: str = "estimate",
    gt_name: str = "ground truth",
) -> tuple[Trajectory, Trajectory]:
    """Matched copies ``(est, gt)`` of equal length.

    ``by_index`` pairs pose ``i`` with pose ``i`` (KITTI files without timestamps); both must
    then have the same length.

    Raises:
        TrajectoryError: empty input, different lengths with ``by_index``, or no common timestamps.
    """
    for traj, name in ((est, est_name), (gt, gt_name)):
        if len(traj) == 0:
            raise TrajectoryError(f"{name}: the trajectory is empty")
    if by_index:
        if len(est) != len(gt):
            raise TrajectoryError(
                f"{est_name} has {len(est)} poses and {gt_name} {len(gt)}: trajectories without timestamps "
                "(KITTI) are associated by line index and need the same number of poses; "
                "give timestamps (--est-times/--gt-times) instead"
            )
        return est, gt
    i_est, i_gt = associate_timestamps(est.timestamps, gt.timestamps, max_diff, offset)
    if len(i_est) == 0:
        raise TrajectoryError(
            f"no common timestamps between {est_name} ({est.timestamps[0]:.6f}..{est.timestamps[-1]:.6f} s) "
            f"and {gt_name} ({gt.timestamps[0]:.6f}..{gt.timestamps[-1]:.6f} s) with max difference "
            f"{max_diff} s and offset {offset} s; check that both use the same clock, or raise "
            "--max-diff / set --offset"
        )
    return est.subset(i_est), gt.subset(i_gt)
