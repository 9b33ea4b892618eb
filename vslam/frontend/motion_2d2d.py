"""2D-2D motion: the essential matrix between a reference frame and the current one,
``C_n = C_ref T_n`` (Scaramuzza & Fraundorfer, "Visual Odometry", RAM 2011), its translation
scaled by the keypoint depths (stereo / RGB-D) or, for monocular, by the relative scale of points
triangulated from consecutive pairs (ibid. eq. (16)). The reference advances once the parallax
suffices or too few correspondences are left."""
from __future__ import annotations

import time

import numpy as np

from vslam.frontend.config import FrontendConfig
from vslam.frontend.motion_model import MotionModel
from vslam.frontend.observation import Observation
from vslam.geometry.camera import PinholeCamera
from vslam.geometry.epipolar import essential_pose
from vslam.geometry.lie import inv_se3, make_T
from vslam.geometry.triangulation import ray_parallax_deg, reprojection_error_depth, triangulate
from vslam.map.matching import brute_force_match


class TwoViewTracker:
    """The 2D-2D reference frame and the pose of each frame relative to it (see the module docstring)."""

    def __init__(self, cfg: FrontendConfig, camera: PinholeCamera, sensor: str, binary: bool,
                 timers: dict[str, float]) -> None:
        self.cfg = cfg
        self.camera = camera
        self.K = camera.K
        self.sensor = sensor
        self.binary = binary
        self.timers = timers
        self.ref: Observation | None = None
        self.T_world_ref: np.ndarray | None = None
        self.mono_X: tuple[np.ndarray, np.ndarray] | None = None  # (kp idx, X in the reference frame), monocular
        self._pending_X: tuple[np.ndarray, np.ndarray] | None = None  # the same for the current frame

    def reset(self) -> None:
        self.ref = None
        self.mono_X = None

    def set_reference(self, obs: Observation, T_world_cam: np.ndarray, X: np.ndarray | None = None,
                      X_idx: np.ndarray | None = None) -> None:
        """``obs`` becomes the reference; ``X`` (points in its camera frame) at keypoints ``X_idx``
        give the monocular scale of the next pair."""
        self.ref = obs
        self.T_world_ref = T_world_cam.copy()
        obs.ref2d_idx = np.arange(len(obs), dtype=np.int64)
        self.mono_X = None if X is None else (X_idx, X)

    def _correspondences(self, obs: Observation) -> tuple[np.ndarray, np.ndarray]:
        cfg = self.cfg
        if cfg.association == "match":
            i1, i2 = brute_force_match(self.ref.descriptors, obs.descriptors, self.binary, ratio=cfg.two_view.match_ratio,
                                       max_distance=cfg.matching.max_descriptor_distance if self.binary else None)
            obs.point_ids[:] = -1
            return i1, i2
        r = obs.ref2d_idx if obs.ref2d_idx is not None else np.full(len(obs), -1)
        i2 = np.flatnonzero(r >= 0)
        return r[i2], i2

    def pose(self, obs: Observation, motion_model: MotionModel) -> tuple[np.ndarray | None, int]:
        """``(T_world_cam or None, inlier correspondences)``."""
        cfg = self.cfg
        ref = self.ref
        t0 = time.perf_counter()
        if ref is None or len(ref) < 8 or len(obs) < 8:
            return None, 0
        i1, i2 = self._correspondences(obs)
        self.timers["association"] += time.perf_counter() - t0
        t0 = time.perf_counter()
        try:
            if len(i1) < cfg.tracking.min_inliers:
                return None, int(len(i1))
            x1, x2 = ref.uv_undist[i1], obs.uv_undist[i2]
            # with depth the rotation must come from E even at small parallax (a rotation-only fit would
            # absorb sideways translation); the translation then comes from the depths
            min_par = cfg.two_view.min_parallax_deg if self.sensor == "mono" else 0.0
            R, t, mask, status = essential_pose(x1, x2, self.K, cfg.tracking.essential_px, min_par)
            if R is None or mask.sum() < cfg.tracking.min_inliers:
                return None, int(mask.sum())
            if self.sensor != "mono":
                T_world_cam = self._scaled_by_depth(ref, obs, i1, i2, mask, R, t, status)
                if T_world_cam is None:
                    return None, int((mask & np.isfinite(ref.depth[i1]) & np.isfinite(obs.depth[i2])).sum())
            elif status == "ok":
                t_m = self._mono_scale(ref, obs, i1, i2, mask, R, t, motion_model)
                T_world_cam = self.T_world_ref @ inv_se3(make_T(R, t_m))
            else:
                # too little parallax for a translation: rotation from the images, position from
                # the constant-velocity model; the reference stays
                T_world_cam = motion_model.predict()
                T_world_cam[:3, :3] = self.T_world_ref[:3, :3] @ R.T
            tv = cfg.two_view
            if status == "ok" or len(i1) < tv.advance_ratio * len(ref) \
                    or len(i1) < tv.advance_min_inliers_factor * cfg.tracking.min_inliers:
                X = self._pending_X
                self.set_reference(obs, T_world_cam, None if X is None else X[1], None if X is None else X[0])
            self._pending_X = None
            return T_world_cam, int(mask.sum())
        finally:
            self.timers["pose"] += time.perf_counter() - t0

    def _scaled_by_depth(self, ref, obs, i1, i2, mask, R, t, status) -> np.ndarray | None:
        """Stereo / RGB-D: the translation from the keypoint depths (None with fewer than 6)."""
        z1, z2 = ref.depth[i1], obs.depth[i2]
        both = mask & np.isfinite(z1) & np.isfinite(z2)
        if both.sum() < 6:
            return None
        x1, x2 = ref.uv_undist[i1], obs.uv_undist[i2]
        Xp = self.camera.backproject(x1[both], z1[both])
        Xc = self.camera.backproject(x2[both], z2[both])
        diff = Xc - Xp @ R.T
        if status == "ok" and self.cfg.two_view.depth_scale_only:
            t_m = float(np.median(diff @ t)) * t  # scale of the unit translation from depth
        else:  # the rotation from the images, the translation from the depths
            t_m = np.median(diff, axis=0)
        return self.T_world_ref @ inv_se3(make_T(R, t_m))

    def _mono_scale(self, ref: Observation, obs: Observation, i1, i2, mask, R, t, motion_model: MotionModel) -> np.ndarray:
        """Monocular 2D-2D translation with the relative scale: points triangulated from the previous
        pair and from this pair, both in the reference camera frame, compared by the median ratio of
        their distances (Scaramuzza & Fraundorfer, "Visual Odometry", RAM 2011, eq. (16))."""
        tv = self.cfg.two_view
        T_cur_ref_unit = make_T(R, t)
        idx = np.flatnonzero(mask)
        X = triangulate(np.eye(4), T_cur_ref_unit, self.K, ref.uv_undist[i1[idx]], obs.uv_undist[i2[idx]])
        e1, za = reprojection_error_depth(np.eye(4), self.K, X, ref.uv_undist[i1[idx]])
        e2, zb = reprojection_error_depth(T_cur_ref_unit, self.K, X, obs.uv_undist[i2[idx]])
        good = (za > 0) & (zb > 0) & (e1 < tv.max_reproj_px) & (e2 < tv.max_reproj_px) \
            & (ray_parallax_deg(np.eye(4), inv_se3(T_cur_ref_unit), X) > tv.min_point_parallax_deg)
        # fallback: the distance the motion model expects between the reference and this frame
        T_pred = motion_model.predict()
        s = float(np.linalg.norm(T_pred[:3, 3] - self.T_world_ref[:3, 3])) if T_pred is not None else 1.0
        if self.mono_X is not None and good.sum() >= tv.scale_min_points:
            old_idx, old_X = self.mono_X
            lookup = np.full(len(ref), -1, np.int64)
            lookup[old_idx] = np.arange(len(old_idx))
            j = lookup[i1[idx]]
            common = good & (j >= 0)
            if common.sum() >= tv.scale_min_points:
                ratio = np.linalg.norm(old_X[j[common]], axis=1) / np.linalg.norm(X[common], axis=1)
                s = float(np.median(ratio))
        if not np.isfinite(s) or s <= 0:
            s = 1.0
        Xs = X[good] * s
        self._pending_X = (i2[idx[good]], Xs @ R.T + s * t)  # in the current frame, for the next pair
        return s * t
