"""Write-back helpers of local BA: points left out of a monocular BA follow the corrected
keyframes, and moved points get new normals and distance ranges (see :mod:`vslam.backend.local_mapping`)."""
from __future__ import annotations

import numpy as np

from vslam.backend.local_problem import row_norms
from vslam.backend.local_problem_kernels import unit_ray_sums
from vslam.backend.problem import BAProblem, BAResult
from vslam.geometry.camera import PinholeCamera
from vslam.map.map import Map


class PointWriteback:
    """Point updates after a BA result was written into the map."""

    def __init__(self, map_: Map, camera: PinholeCamera, max_reproj_px: float = 4.0,
                 min_parallax_deg: float = 1.0) -> None:
        self.map = map_
        self.camera = camera
        self.max_reproj_px = float(max_reproj_px)  # the retriangulation gate (backend.mono.retriangulate_*)
        self.min_parallax_deg = float(min_parallax_deg)

    def transport_left_out(self, pt: np.ndarray, corrections: dict[int, np.ndarray]) -> None:
        """``mono.left_out=transport``: a point left out of a monocular BA keeps its coordinates in
        its reference (first) keyframe, i.e. moves with that keyframe's correction
        ``X <- T_after T_before^-1 X`` (as loop correction moves points, ORB-SLAM2 CorrectLoop), so
        tracking does not meet stale points next to corrected poses."""
        store = self.map.points
        ids = np.unique(pt)
        ids = ids[store.alive[ids]]
        ref = store.first_kf[ids]
        for kid, D in corrections.items():
            m = ids[ref == kid]
            if len(m):
                store.position[m] = store.position[m] @ D[:3, :3].T + D[:3, 3]

    def retriangulate_left_out(self, pt: np.ndarray, kf: np.ndarray, uv: np.ndarray,
                                corrections: dict[int, np.ndarray]) -> None:
        """``mono.left_out=retriangulate``: points left out of a monocular BA (two-view points) are triangulated
        again (:func:`vslam.geometry.triangulation.triangulate`, linear DLT, HZ 12.2) from their two
        observations with the corrected keyframe poses, so tracking does not meet stale points next to
        corrected poses (see the config for the measured trade-off). A point whose new triangulation
        fails :func:`~vslam.geometry.triangulation.good_triangulation_mask` (in front of both keyframes,
        within ``max_reproj_px`` in both, ``min_parallax_deg`` of parallax) keeps its position: with
        the cheirality test alone
        a low-parallax point could land anywhere on its ray (7-Scenes mono: the segment's scale
        drifted 2.6x, see docs/architecture.md)."""
        from vslam.geometry.triangulation import good_triangulation_mask, triangulate

        store = self.map.points
        order = np.lexsort((kf, pt))
        pt, kf, uv = pt[order], kf[order], uv[order]
        starts = np.flatnonzero(np.r_[True, pt[1:] != pt[:-1]])
        counts = np.diff(np.r_[starts, len(pt)])
        s = starts[counts >= 2]
        ids, ka, kb, ua, ub = pt[s], kf[s], kf[s + 1], uv[s], uv[s + 1]
        moved = np.isin(ka, list(corrections)) | np.isin(kb, list(corrections))
        sel = moved & store.alive[ids]
        pairs = np.unique(np.stack([ka[sel], kb[sel]], axis=1), axis=0)
        for a, b in pairs.tolist():
            m = sel & (ka == a) & (kb == b)
            Ta, Tb = self.map.keyframes[a].T_cam_world, self.map.keyframes[b].T_cam_world
            X = triangulate(Ta, Tb, self.camera.K, ua[m], ub[m])
            ok = good_triangulation_mask(Ta, Tb, self.camera.K, ua[m], ub[m], X, max_reproj_px=self.max_reproj_px,
                                         min_parallax_deg=self.min_parallax_deg)
            store.position[ids[m][ok]] = X[ok]

    def update_normals(self, problem: BAProblem, result: BAResult, good: np.ndarray) -> None:
        """ORB-SLAM's UpdateNormalAndDepth after the points moved: the viewing direction is the mean
        unit ray from the observing keyframes, the distance range is rescaled to the new distance
        from one observing keyframe (the tracker's visibility test uses both)."""
        store = self.map.points
        pt_row = problem.pt_index(problem.obs_pt)
        kf_row = problem.kf_index(problem.obs_kf)
        # per observation the ray length, per point the sum of its unit rays in observation order (one
        # compiled loop; the arithmetic of ray / max(|ray|, 1e-12) summed by np.bincount)
        acc = np.zeros((problem.num_points, 3))
        dist = np.empty(len(pt_row))
        unit_ray_sums(np.ascontiguousarray(result.X_world, dtype=float),
                      np.ascontiguousarray(result.T_world_cam, dtype=float), pt_row, kf_row, acc, dist)
        norm = row_norms(acc)
        ok = good & (norm > 1e-9)
        ids = problem.pt_ids[ok]
        store.normal[ids] = acc[ok] / norm[ok, None]
        # distance range from the last observation of each point (scale-invariance, ORB-SLAM sec. III-C)
        last = np.full(problem.num_points, -1, np.int64)
        last[pt_row] = np.arange(len(pt_row))
        has = ok & (last >= 0)
        o = last[has]
        ids = problem.pt_ids[has]
        old_max, old_min = store.max_distance[ids], store.min_distance[ids]
        ratio = np.where((old_min > 0) & np.isfinite(old_max), old_max / np.maximum(old_min, 1e-12), 1.0)
        new_max = dist[o] * problem.obs_sigma[o]
        store.max_distance[ids] = new_max
        store.min_distance[ids] = new_max / np.maximum(ratio, 1.0)

