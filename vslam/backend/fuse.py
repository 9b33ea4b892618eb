"""Fusing the new keyframe's points with its neighbours' (ORB-SLAM2 SearchInNeighbors), step 1b
of :mod:`vslam.backend.local_mapping`."""
from __future__ import annotations

from typing import Callable

import numpy as np

from vslam.backend import fuse_kernels
from vslam.backend.config import BackendConfig
from vslam.geometry.camera import PinholeCamera
from vslam.map.fusion import apply_remap, new_remap
from vslam.map.keyframe import KeyFrame
from vslam.map.map import Map
from vslam.map.mappoint import unique_ids


class NeighbourFusion:
    """``fuse_neighbours(kf_id)``; ``window(kf) -> (optimized ids, constant ids)`` gives the neighbours."""

    def __init__(self, map_: Map, camera: PinholeCamera, sensor: str, config: BackendConfig, scale_factor: float,
                 window: Callable[[KeyFrame], tuple[list[int], list[int]]], counts: dict) -> None:
        self.map = map_
        self.camera = camera
        self.sensor = sensor
        self.config = config
        self.scale_factor = scale_factor
        self._window = window
        self.counts = counts

    def fuse_neighbours(self, kf_id: int) -> None:
        """ORB-SLAM2 ``SearchInNeighbors`` (Mur-Artal & Tardos 2017, Sec. VI-B): project the window
        keyframes' points into the new keyframe and the new keyframe's points into the window
        keyframes; a descriptor match whose reprojection (and disparity) error passes the chi-square
        test adds the observation, or fuses two points that are one (the one with fewer
        observations is replaced everywhere). This links keyframes through shared points, which is
        what gives local BA its constraints."""
        kf = self.map.keyframes.get(kf_id)
        if kf is None or kf.bad or kf.descriptors is None or self.map.points.descriptor is None:
            return
        window, _ = self._window(kf)
        neighbours = [self.map.keyframes[k] for k in window if k != kf_id]
        if not neighbours:
            return
        store = self.map.points
        remap = new_remap(len(store))
        # neighbours' points -> new keyframe
        pts = self.map.local_point_ids([k.id for k in neighbours])
        n_fused = self._fuse_into(kf, pts, remap)
        # new keyframe's points -> each neighbour
        own = kf.observed_ids()
        own = unique_ids(len(store), own[store.alive[own]])
        for nb in neighbours:
            n_fused += self._fuse_into(nb, own, remap)
        if n_fused:
            apply_remap(self.map.keyframes.values(), remap)
        self.map.update_covisibility(kf_id)
        self.counts["fused_points"] = self.counts.get("fused_points", 0) + n_fused

    def _fuse_into(self, kf: KeyFrame, pts: np.ndarray, remap: np.ndarray) -> int:
        """Match points ``pts`` (sorted, unique) into keyframe ``kf``; returns the number of points fused away."""
        from vslam.map.matching import guided_match, project_local_points

        store = self.map.points
        if len(kf.uv_undist) == 0:
            return 0
        # the alive points of pts that kf does not observe yet (sorted unique pts: no id-range scan)
        pts = fuse_kernels.candidate_points(pts, store.alive, kf.point_ids, len(store))
        if len(pts) == 0:
            return 0
        vis, uv, z = project_local_points(store, pts, kf.T_cam_world, self.camera)
        if len(vis) == 0:
            return 0
        binary = kf.descriptors.dtype == np.uint8
        m, k, _ = guided_match(uv, store.descriptor[vis], kf.uv_undist, kf.descriptors, self.config.fusion.radius_px,
                               binary, self.config.fusion.max_descriptor_distance if binary else None,
                               ratio=self.config.fusion.ratio,
                               kp_tree=kf.keypoint_tree)  # built only if the grid search needs it
        if len(m) == 0:
            return 0
        sigma2 = np.power(self.scale_factor, 2.0 * kf.octave[k].astype(float))
        use_disp = self.sensor != "mono" and kf.u_right is not None
        bf, u0, u_right = 0.0, sigma2, sigma2  # (unused without a disparity)
        if use_disp:
            if self.sensor == "stereo":
                bf, u0 = self.camera.fx * float(self.camera.baseline), kf.uv[:, 0]
            else:
                bf, u0 = self.camera.fx * self.config.local.rgbd_virtual_baseline, kf.uv_undist[:, 0]
            u_right = kf.u_right
        # chi-square test, new observations, and the (loser, winner) pairs of two points that are one
        # (the better observed survives; ``remap``: fused earlier in this pass)
        loser, winner = fuse_kernels.fuse_matches(
            vis[m], k, z[m], uv[m], kf.uv_undist, sigma2, np.ascontiguousarray(u0, np.float64),
            np.asarray(u_right, np.float64), float(bf), use_disp, float(self.config.local.chi2_mono),
            float(self.config.local.chi2_stereo), kf.point_ids, store.alive, store.n_obs, remap)
        return self.map.merge_points(loser, winner, remap) if len(loser) else 0
