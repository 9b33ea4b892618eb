"""The map: keyframes, map points (columnar store) and the covisibility graph.

Covisibility (ORB-SLAM, Mur-Artal et al. 2015, sec. III-D): two keyframes are linked with a
weight equal to the number of map points both observe.
"""
from __future__ import annotations

import logging

import numpy as np

from vslam.map import map_kernels
from vslam.map.keyframe import KeyFrame
from vslam.map.mappoint import MapPoint, MapPointStore, unique_ids

log = logging.getLogger(__name__)


class Map:
    """Keyframes by id, the :class:`MapPointStore`, and covisibility weights."""

    def __init__(self) -> None:
        self.keyframes: dict[int, KeyFrame] = {}
        self.points = MapPointStore()
        self.covisibility: dict[int, dict[int, int]] = {}
        self._next_kf_id = 0
        # incremented by loop closing each time it moves the map (pose graph, fusion): an optimization
        # whose problem was snapshot before (realtime mode) must drop its now stale result
        self.loop_epoch = 0
        # provenance of the segments (vslam.map.segments.SegmentRecord rows); empty: one run's own
        self.segments: list = []
        # visual-inertial maps: the world is gravity-aligned (z up) and metric since the IMU
        # initialization (vslam.backend.inertial_mapping); loop corrections and segment joins are then
        # 4-DoF (position + yaw, vslam.map.pose_graph_4dof). Saved in map.json ``map_attributes``.
        self.gravity_aligned: bool = False

    # ------------------------------------------------------------------ keyframes
    def next_keyframe_id(self) -> int:
        return self._next_kf_id

    def add_keyframe(self, kf: KeyFrame) -> None:
        """Insert ``kf`` and link it in the covisibility graph to every keyframe sharing points."""
        self.keyframes[kf.id] = kf
        self._next_kf_id = max(self._next_kf_id, kf.id + 1)
        ids = kf.observed_ids()
        ids = ids[self.points.first_kf[ids] != kf.id]  # points created with this keyframe count it already
        self.points.n_obs[ids] += 1
        self.points.last_seen_kf[ids] = kf.id
        self.covisibility[kf.id] = {}
        self.update_covisibility(kf.id)

    def update_covisibility(self, kf_id: int, min_weight: int = 1) -> None:
        """Recompute ``kf_id``'s links: per keyframe, the count of its ``point_ids`` this keyframe
        observes (:func:`vslam.map.map_kernels.count_flagged` each; ``-1``, no point, hits the flag
        array's last entry, ``False``)."""
        kf = self.keyframes[kf_id]
        mine = np.zeros(len(self.points) + 1, dtype=bool)  # the points this keyframe observes; [-1]: none
        mine[kf.observed_ids()] = True
        links = self.covisibility.setdefault(kf_id, {})
        others = [o for o in self.keyframes.values() if o.id != kf_id and o.segment == kf.segment and not o.bad]
        if not others or not mine.any():
            return
        count = map_kernels.count_flagged
        weights = np.array([count(mine, o.point_ids) if o.point_ids.dtype == np.int64
                            else np.count_nonzero(mine[o.point_ids]) for o in others], np.int64)
        for j in np.flatnonzero(weights >= min_weight):
            w = int(weights[j])
            links[others[j].id] = w
            self.covisibility.setdefault(others[j].id, {})[kf_id] = w

    def covisible(self, kf_id: int, n: int | None = None) -> list[int]:
        """Keyframes linked to ``kf_id``, strongest first (at most ``n``)."""
        links = self.covisibility.get(kf_id, {})
        order = sorted(links, key=lambda k: -links[k])
        return order if n is None else order[:n]

    def local_keyframes(self, kf_id: int, n: int) -> list[int]:
        """``kf_id`` and its ``n`` most covisible keyframes."""
        return [kf_id] + self.covisible(kf_id, n)

    def local_point_ids(self, kf_ids: list[int]) -> np.ndarray:
        """Unique alive map points observed by the given keyframes."""
        if not kf_ids:
            return np.zeros(0, dtype=np.int64)
        ids = unique_ids(len(self.points), *[self.keyframes[k].observed_ids() for k in kf_ids])
        return ids[self.points.alive[ids]]

    def segment_gravity_aligned(self, segment: int) -> bool:
        """Whether ``segment`` lives in the gravity-aligned world: the map is (:attr:`gravity_aligned`)
        and the segment's IMU is initialized, i.e. its keyframes carry ``extra["imu_velocity"]`` (set
        from the IMU initialization on). A segment started later (tracking lost, or a session
        continuing a saved map) is in its own visual world until its own IMU initialization. A map
        whose keyframes carry no velocity at all (the initialization moved the whole map, every
        segment with it) counts as aligned throughout."""
        if not self.gravity_aligned:
            return False
        kfs = [k for k in self.keyframes.values() if not k.bad]
        if not any("imu_velocity" in k.extra for k in kfs):
            return True
        return any("imu_velocity" in k.extra for k in kfs if k.segment == segment)

    # ------------------------------------------------------------------ points
    def point(self, pid: int) -> MapPoint:
        """A :class:`MapPoint` snapshot with its observations ``{keyframe id: keypoint index}``."""
        mp = self.points.get(pid)
        for kf in self.keyframes.values():
            idx = np.flatnonzero(kf.point_ids == pid)
            if len(idx):
                mp.observations[kf.id] = int(idx[0])
        return mp

    def cull_points(self, min_found_ratio: float, min_visible: int = 6) -> int:
        """Kill points that were predicted visible often but rarely matched (ORB-SLAM point culling)."""
        n = len(self.points)
        p = self.points
        bad = p.alive[:n] & (p.visible[:n] >= min_visible) & (p.found[:n] < min_found_ratio * p.visible[:n])
        if bad.any():
            p.alive[:n][bad] = False
        return int(bad.sum())

    def merge_points(self, loser: np.ndarray, winner: np.ndarray, remap: np.ndarray) -> int:
        """Fuse duplicated map points: each ``loser[i]`` becomes ``winner[i]`` (ORB-SLAM's
        MapPoint::Replace). Pairs that are the same point or invalid (``-1``) are skipped, a loser
        is merged once; its observation count moves to the winner and it dies. ``remap`` (old id ->
        surviving id, ``remap[-1] == -1``) records the merges so the caller can rewrite
        ``KeyFrame.point_ids``. Returns the number of points merged away."""
        sel = (loser != winner) & (loser >= 0) & (winner >= 0)
        loser, winner = loser[sel], winner[sel]
        _, first = np.unique(loser, return_index=True)
        loser, winner = loser[first], winner[first]
        if len(loser) == 0:
            return 0
        store = self.points
        remap[loser] = winner
        np.add.at(store.n_obs, winner, store.n_obs[loser])
        store.alive[loser] = False
        store.n_obs[loser] = 0
        return int(len(loser))

    def limit_points(self, max_points: int, keep_kf_ids: list[int]) -> None:
        """Keep memory flat: when over ``max_points``, drop the points last seen longest ago (outside
        the local keyframes) and compact the store, remapping every keyframe's ``point_ids``."""
        p = self.points
        if p.n_alive <= max_points:
            return
        n = len(p)
        protected = np.zeros(n, dtype=bool)
        if keep_kf_ids:
            protected[self.local_point_ids(keep_kf_ids)] = True
        cand = np.flatnonzero(p.alive[:n] & ~protected)
        excess = p.n_alive - max_points
        if excess > 0 and len(cand):
            order = cand[np.argsort(p.last_seen_kf[cand], kind="stable")]
            p.alive[order[:excess]] = False
        self.compact()

    def compact(self) -> np.ndarray:
        remap = self.points.compact()
        for kf in self.keyframes.values():
            pid = kf.point_ids
            kf.point_ids = np.where(pid >= 0, remap[np.clip(pid, 0, len(remap) - 2)], -1)
        return remap

    # ------------------------------------------------------------------ stats
    @property
    def n_keyframes(self) -> int:
        return len(self.keyframes)

    @property
    def n_points(self) -> int:
        return self.points.n_alive
