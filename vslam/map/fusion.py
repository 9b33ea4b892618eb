"""Point fusion bookkeeping shared by local mapping and loop closing (ORB-SLAM's
``MapPoint::Replace``): a remap array ``old id -> surviving id`` filled by
:meth:`vslam.map.map.Map.merge_points`, then applied to every keyframe's ``point_ids``.

Example:
    >>> remap = new_remap(len(slam_map.points))             # doctest: +SKIP
    >>> n = slam_map.merge_points(loser, winner, remap)      # doctest: +SKIP
    >>> if n: apply_remap(slam_map.keyframes.values(), remap)  # doctest: +SKIP
"""
from __future__ import annotations

from typing import Iterable

import numpy as np

from vslam.map.keyframe import KeyFrame


def new_remap(n_points: int) -> np.ndarray:
    """The identity remap over ``n_points`` ids plus a last entry ``-1`` (so ``remap[-1] == -1``
    maps "no point" to itself)."""
    remap = np.arange(n_points + 1, dtype=np.int64)
    remap[-1] = -1
    return remap


def apply_remap(keyframes: Iterable[KeyFrame], remap: np.ndarray, chain_rounds: int = 4) -> None:
    """Follow merge chains (``a -> b -> c``) to the final survivor, ``chain_rounds`` steps, then
    rewrite each keyframe's ``point_ids`` through ``remap`` (``-1`` stays ``-1``)."""
    moved = np.flatnonzero(remap[:-1] != np.arange(len(remap) - 1))
    for _ in range(chain_rounds):
        remap[moved] = remap[remap[moved]]
    for k in keyframes:
        pid = k.point_ids
        k.point_ids = np.where(pid >= 0, remap[np.where(pid >= 0, pid, -1)], -1)
