"""Timestamp association of an estimated and a ground-truth trajectory.

Nearest-neighbour matching as in the TUM RGB-D benchmark's ``associate.py`` (Sturm et al.,
IROS 2012) and evo's ``sync.matching_time_indices``: every timestamp of the *shorter*
trajectory is paired with the nearest timestamp of the longer one (ties go to the earlier one)
when they differ by at most ``max_diff`` seconds, after adding ``offset`` to the estimate's
timestamps. The result is made one-to-one: a pose of the longer trajectory claimed twice keeps
only its closest partner (evo keeps both; they differ only when the shorter trajectory has
stamps closer than ``2 * max_diff``).
"""
from __future__ import annotations

import numpy as np

from vslam.errors import TrajectoryError
from vslam.trajectory import Trajectory


def match_timestamps(
    stamps_a: np.ndarray, stamps_b: np.ndarray, max_diff: float = 0.01
) -> tuple[np.ndarray, np.ndarray]:
    """For each of ``stamps_a`` the nearest of the sorted ``stamps_b`` within ``max_diff``.

    Returns index arrays ``(ia, ib)``, increasing in ``ia``, one-to-one in ``ib``.
    """
    a = np.asarray(stamps_a, dtype=float).reshape(-1)
    b = np.asarray(stamps_b, dtype=float).reshape(-1)
    if len(a) == 0 or len(b) == 0:
        return np.zeros(0, dtype=int), np.zeros(0, dtype=int)
    idx = np.searchsorted(b, a, side="right")
    hi = np.minimum(idx, len(b) - 1)
    lo = np.maximum(idx - 1, 0)
    d_hi = np.abs(b[hi] - a)
    d_lo = np.abs(a - b[lo])
    take_hi = d_hi < d_lo
    ib = np.where(take_hi, hi, lo)
    diff = np.where(take_hi, d_hi, d_lo)
    ia = np.flatnonzero(diff <= max_diff)
    ib, diff = ib[ia], diff[ia]
    # One-to-one: for every b claimed more than once keep the closest a (stable: the first on ties).
    order = np.lexsort((ia, diff, ib))
    keep = np.ones(len(order), dtype=bool)
    keep[1:] = ib[order][1:] != ib[order][:-1]
    chosen = np.sort(order[keep])
    return ia[chosen], ib[chosen]


def associate(
    est_stamps: np.ndarray, gt_stamps: np.ndarray, max_diff: float = 0.01, offset: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs ``(i_est, i_gt)`` with ``|est_t + offset - gt_t| <= max_diff``, sorted by time.

    The shorter trajectory drives the search (as evo), so no pose of it is lost to a denser one.
    """
    est = np.asarray(est_stamps, dtype=float).reshape(-1) + offset
    gt = np.asarray(gt_stamps, dtype=float).reshape(-1)
    if len(gt) >= len(est):
        i_est, i_gt = match_timestamps(est, gt, max_diff)
    else:
        i_gt, i_est = match_timestamps(gt, est, max_diff)
        order = np.argsort(i_est, kind="stable")
        i_est, i_gt = i_est[order], i_gt[order]
    return i_est, i_gt


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
    i_est, i_gt = associate(est.timestamps, gt.timestamps, max_diff, offset)
    if len(i_est) == 0:
        raise TrajectoryError(
            f"no common timestamps between {est_name} ({est.timestamps[0]:.6f}..{est.timestamps[-1]:.6f} s) "
            f"and {gt_name} ({gt.timestamps[0]:.6f}..{gt.timestamps[-1]:.6f} s) with max difference "
            f"{max_diff} s and offset {offset} s; check that both use the same clock, or raise "
            "--max-diff / set --offset"
        )
    return est.subset(i_est), gt.subset(i_gt)
