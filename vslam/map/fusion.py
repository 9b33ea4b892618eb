"""Point fusion bookkeeping shared by local mapping and loop closing (ORB-SLAM's
``MapPoint::Replace``): a remap array ``old id -> surviving id`` filled by
:meth:`vslam.map.map.Map.merge_points`, then applied to every keyframe's ``point_ids``.

Example:
    >>> remap = new_remap(len(slam_map.points))             # doctest: +SKIP
    >>> n = slam_map.merge_points(loser, winner, remap)      # doctest: +SKIP
    >>> if n: apply_remap(slam_map.keyframes.values(), remap)  # doctest: +SKIP
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Iterable

import numpy as np

from vslam.map import fusion_kernels
from vslam.map.keyframe import KeyFrame

if TYPE_CHECKING:
    from vslam.map.map import Map


def new_remap(n_points: int) -> np.ndarray:
    """The identity remap over ``n_points`` ids plus a last entry ``-1`` (so ``remap[-1] == -1``
    maps "no point" to itself)."""
    remap = np.arange(n_points + 1, dtype=np.int64)
    remap[-1] = -1
    return remap


def apply_remap(keyframes: Iterable[KeyFrame], remap: np.ndarray, chain_rounds: int = 4) -> None:
    """Follow merge chains (``a -> b -> c``) to the final survivor, ``chain_rounds`` steps, then
    rewrite each keyframe's ``point_ids`` through ``remap`` (``-1`` stays ``-1``: ``remap`` comes from
    :func:`new_remap`, whose last entry is ``-1`` and stays so, as merges never name ``-1``)."""
    if remap.dtype != np.int64:  # (new_remap's dtype; others by NumPy)
        moved = np.flatnonzero(remap[:-1] != np.arange(len(remap) - 1))
        for _ in range(chain_rounds):
            remap[moved] = remap[remap[moved]]
        for k in keyframes:
            k.point_ids = remap[k.point_ids]  # -1 (no point, KeyFrame.point_ids) -> remap[-1] == -1
        return
    fusion_kernels.follow_chains(remap, chain_rounds)
    for k in keyframes:
        pid = k.point_ids
        # -1 (no point, KeyFrame.point_ids) -> remap[-1] == -1
        k.point_ids = fusion_kernels.remap_ids(remap, pid) if pid.dtype == np.int64 else remap[pid]


def assign_observations(slam_map: "Map", kf: KeyFrame, kp: np.ndarray, pids: np.ndarray, remap: np.ndarray) -> int:
    """Keypoints ``kp`` of ``kf`` observe the points ``pids`` (which survive): a free keypoint (no
    point, or a dead one) takes the point; a keypoint observing another point has that point merged
    into ``pids`` (:meth:`Map.merge_points`, recorded in ``remap``). A point ``kf`` already observes
    through another keypoint is skipped (one observation per keyframe). Returns the points merged
    away. Used by loop closing (a loop's query side), segment joining and map merging."""
    store = slam_map.points
    kp, pids = np.asarray(kp, np.int64), np.asarray(pids, np.int64)
    if len(kp) == 0:
        return 0
    dup_obs = np.isin(pids, kf.point_ids[kf.point_ids >= 0]) & (kf.point_ids[kp] != pids)
    kp, pids = kp[~dup_obs], pids[~dup_obs]
    cur = kf.point_ids[kp]
    free = (cur < 0) | ~store.alive[np.where(cur >= 0, cur, 0)]
    kf.point_ids[kp[free]] = pids[free]
    np.add.at(store.n_obs, pids[free], 1)
    dup = ~free & (cur != pids)
    return slam_map.merge_points(remap[cur[dup]], remap[pids[dup]], remap)
