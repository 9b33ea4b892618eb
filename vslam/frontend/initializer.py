"""Monocular map initialization from two views (2D-2D).

A reference frame is kept until a later frame has enough matches and enough parallax: the
relative pose comes from the essential matrix (five-point RANSAC + cheirality), the matches are
triangulated and the map is scaled so that the median depth is 1 (as ORB-SLAM's monocular
initializer, Mur-Artal et al. 2015, sec. IV). Pure rotation (median rotation-compensated parallax
below the threshold) never initializes.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from vslam.frontend.config import FrontendConfig
from vslam.frontend.observation import Observation
from vslam.geometry.epipolar import essential_pose
from vslam.geometry.lie import inv_se3, make_T
from vslam.geometry.triangulation import ray_parallax_deg, reprojection_error_depth, triangulate

log = logging.getLogger(__name__)


@dataclass
class TwoViewInit:
    """Result: ``T_cur_ref`` (unit median depth), the matched indices and the points in the reference frame."""

    T_cur_ref: np.ndarray
    ref_idx: np.ndarray
    cur_idx: np.ndarray
    X_ref: np.ndarray  # (M, 3) points in the reference camera frame
    median_parallax_deg: float


class MonoInitializer:
    """Holds the reference frame and tries two-view initialization against later frames."""

    def __init__(self, cfg: FrontendConfig, K: np.ndarray) -> None:
        self.cfg = cfg
        self.K = K
        self.ref: Observation | None = None
        self.ref_frame_index = -1
        self.ref_timestamp = 0.0
        self.attempts = 0
        self.pending: list[tuple[float, np.ndarray, np.ndarray]] = []  # frames seen since the reference

    def reset(self) -> None:
        self.ref = None
        self.attempts = 0
        self.pending = []

    def set_reference(self, obs: Observation, frame_index: int, timestamp: float) -> None:
        self.ref = obs
        self.ref_frame_index = frame_index
        self.ref_timestamp = timestamp
        self.attempts = 0
        self.pending = []

    def try_initialize(self, ref_idx: np.ndarray, cur: Observation, cur_idx: np.ndarray) -> TwoViewInit | None:
        """Attempt initialization from correspondences ``ref.uv_undist[ref_idx] <-> cur.uv_undist[cur_idx]``."""
        self.attempts += 1
        cfg = self.cfg
        if self.ref is None or len(ref_idx) < cfg.init.min_matches:
            return None
        x1 = self.ref.uv_undist[ref_idx]
        x2 = cur.uv_undist[cur_idx]
        R, t, mask, status = essential_pose(x1, x2, self.K, cfg.tracking.essential_px * cfg.init.essential_threshold_factor, cfg.init.rotation_parallax_deg)
        if status != "ok" or mask.sum() < cfg.init.min_matches * cfg.init.min_inlier_fraction:
            log.debug("init: status %s, %d inliers", status, int(mask.sum()))
            return None
        T_cur_ref = make_T(R, t)
        X = triangulate(np.eye(4), T_cur_ref, self.K, x1[mask], x2[mask])
        e1, z1 = reprojection_error_depth(np.eye(4), self.K, X, x1[mask])
        e2, z2 = reprojection_error_depth(T_cur_ref, self.K, X, x2[mask])
        T_ref_cur = inv_se3(T_cur_ref)
        par = ray_parallax_deg(np.eye(4), T_ref_cur, X)
        thr = cfg.init.reproj_threshold_factor * cfg.tracking.essential_px
        good = (z1 > 0) & (z2 > 0) & (e1 < thr) & (e2 < thr) & (par > cfg.init.min_point_parallax_deg) & np.all(np.isfinite(X), axis=1)
        if good.sum() < cfg.init.min_matches * cfg.init.min_point_fraction:
            return None
        # ORB-SLAM's test: the 50th largest parallax (init.parallax_rank) must exceed the threshold
        par_sorted = np.sort(par[good])[::-1]
        med_par = float(par_sorted[min(cfg.init.parallax_rank, len(par_sorted) - 1)])
        if med_par < cfg.init.min_parallax_deg:
            return None
        scale = 1.0 / float(np.median(z1[good]))
        T_cur_ref[:3, 3] *= scale
        idx = np.flatnonzero(mask)[good]
        log.info("monocular init: %d points, parallax %.2f deg (rank %d)", len(idx), med_par, cfg.init.parallax_rank)
        return TwoViewInit(T_cur_ref, ref_idx[idx], cur_idx[idx], X[good] * scale, med_par)
