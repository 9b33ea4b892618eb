"""Culling after local BA (step 4 of :mod:`vslam.backend.local_mapping`): points too few keyframes
re-observed (ORB-SLAM2 MapPointCulling) and redundant keyframes (KeyFrameCulling); culled keyframes
follow their parent rigidly."""
from __future__ import annotations

import numpy as np

from vslam.backend.config import BackendConfig
from vslam.backend.local_problem import segment_keyframes
from vslam.geometry.lie import inv_se3
from vslam.map.keyframe import KeyFrame
from vslam.map.map import Map
from vslam.map.mappoint import unique_ids


class Culling:
    """Point and keyframe culling of one map; counts go to ``counts`` (``culled_points``, ``culled_keyframes``)."""

    def __init__(self, map_: Map, config: BackendConfig, counts: dict) -> None:
        self.map = map_
        self.config = config
        self.counts = counts
        self._culled_upto: dict[int, int] = {}  # per segment: points born up to this keyframe were judged

    def cull_points(self, kf_id: int) -> None:
        """Points without observations die; so do points born two keyframes ago (in this segment)
        that fewer than ``cull.min_observations`` keyframes observe (ORB-SLAM2 MapPointCulling, with
        the keyframe count as the age; each point is judged once)."""
        store = self.map.points
        n = len(store)
        if n == 0:
            return
        alive = store.alive[:n]
        dead = alive & (store.n_obs[:n] <= 0)
        k_min = self.config.cull.min_observations
        kf = self.map.keyframes.get(kf_id)
        if k_min > 1 and kf is not None:
            seg_ids = sorted(k.id for k in segment_keyframes(self.map, kf.segment))
            age = self.config.cull.age_keyframes
            if len(seg_ids) >= age:
                upto = seg_ids[-age]  # points born two keyframes ago had their chance to be re-observed
                first = store.first_kf[:n]
                lo = self._culled_upto.get(kf.segment, -1)
                recent = alive & (first > lo) & (first <= upto)
                dead |= recent & (store.n_obs[:n] < k_min)
                self._culled_upto[kf.segment] = upto
        if dead.any():
            store.alive[:n][dead] = False
            self.counts["culled_points"] += int(dead.sum())

    def cull_keyframes(self, kf_id: int) -> None:
        """ORB-SLAM KeyFrameCulling over the covisible keyframes of ``kf_id``: a keyframe whose
        points are >= ``cull.redundant_ratio`` observed by >= ``cull.redundant_min_observers`` other keyframes is flagged bad."""
        store = self.map.points
        kf = self.map.keyframes.get(kf_id)
        if kf is None:
            return
        seg = segment_keyframes(self.map, kf.segment)
        n_recent = self.config.cull.keep_recent_keyframes
        if len(seg) < n_recent + 1:
            return
        first = min(k.id for k in seg)
        recent = {k.id for k in sorted(seg, key=lambda k: k.id)[-n_recent:]}
        for cid in self.map.covisible(kf_id):
            c = self.map.keyframes.get(cid)
            if c is None or c.bad or c.id == first or c.id in recent or c.segment != kf.segment:
                continue
            ids = unique_ids(len(store), c.observed_ids())
            ids = ids[store.alive[ids]]
            if len(ids) == 0:
                continue
            seen = np.zeros(len(ids), np.int64)
            in_o = np.zeros(len(store), dtype=bool)  # per other keyframe: which points it observes
            for oid in self.map.covisibility.get(cid, {}):
                o = self.map.keyframes.get(oid)
                if o is None or o.bad or o.id == cid:
                    continue
                obs = o.observed_ids()
                in_o[obs] = True
                seen += in_o[ids]
                in_o[obs] = False
            if np.mean(seen >= self.config.cull.redundant_min_observers) >= self.config.cull.redundant_ratio:
                self.set_bad(c)

    def set_bad(self, kf: KeyFrame) -> None:
        links = self.map.covisibility.get(kf.id, {})
        parents = [o for o in sorted(links, key=lambda o: (-links[o], o))
                   if o in self.map.keyframes and not self.map.keyframes[o].bad]
        if not parents:
            return
        parent = self.map.keyframes[parents[0]]
        kf.extra["parent"] = parent.id
        kf.extra["T_parent_kf"] = inv_se3(parent.T_world_cam) @ kf.T_world_cam
        kf.bad = True
        for o in list(links):
            self.map.covisibility.get(o, {}).pop(kf.id, None)
        self.map.covisibility[kf.id] = {}
        ids = kf.observed_ids()
        np.subtract.at(self.map.points.n_obs, ids, 1)
        self.counts["culled_keyframes"] += 1

    def update_bad_keyframes(self) -> None:
        """Culled keyframes follow their parent rigidly (so frames referencing them stay placed)."""
        for kf in self.map.keyframes.values():
            if not kf.bad or "parent" not in kf.extra:
                continue
            chain, p = [], kf
            while p.bad and "parent" in p.extra and len(chain) < 100:
                chain.append(p.extra["T_parent_kf"])
                p = self.map.keyframes[p.extra["parent"]]
            T = p.T_world_cam
            for T_rel in reversed(chain):
                T = T @ T_rel
            kf.T_world_cam = T
