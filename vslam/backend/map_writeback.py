"""Write-back helpers of local BA: points left out of a monocular BA follow the corrected
keyframes, and moved points get new normals and distance ranges (see :mod:`vslam.backend.local_mapping`)."""
from __future__ import annotations

import numpy as np

from vslam.backend.local_problem_kernels import normals_and_ranges
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
        # one compiled pass (the arithmetic of the NumPy expressions it replaced, to the bit): per
        # observation the ray and its length, per point the sum of its unit rays in observation order
        # (as np.bincount sums them), the normal (their mean direction) and, from the last observation
        # of each point, the distance range (scale-invariance, ORB-SLAM sec. III-C)
        P = problem.num_points
        normals_and_ranges(np.ascontiguousarray(result.X_world, dtype=float),
                           np.ascontiguousarray(result.T_world_cam, dtype=float), pt_row, kf_row,
                           np.ascontiguousarray(good, dtype=np.bool_), problem.pt_ids, problem.obs_sigma,
                           store.normal, store.max_distance, store.min_distance, np.zeros((P, 3)),
                           np.empty(len(pt_row)), np.empty(P, np.int64))
