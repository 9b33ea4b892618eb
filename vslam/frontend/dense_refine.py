"""RGB-D dense alignment in tracking: a bridge over frames without a feature pose, a refinement
of weak feature poses, and the dense links local BA keeps (``frontend.dense.*``).

All three align this frame's depth (and grey) image to the last tracked frame's
(:func:`vslam.frontend.depth_icp.align_depth`: point-to-plane ICP + photometric error); a result is
kept only when the aligned depths agree (:func:`vslam.frontend.depth_icp.depth_agreement`).
"""
from __future__ import annotations

import logging
import time

import numpy as np

from vslam.datasets.frame import Frame
from vslam.frontend.config import FrontendConfig
from vslam.frontend.depth_icp import align_depth, depth_agreement
from vslam.frontend.motion_model import MotionModel
from vslam.geometry.lie import inv_se3
from vslam.map.dense_links import DenseLink, sample_depth_grid
from vslam.map.map import Map

log = logging.getLogger(__name__)


class DenseTracker:
    """The last tracked RGB-D frame and the dense alignments to it (see the module docstring).

    ``dense_links``: ``{kf_id: DenseLink}`` for keyframes posed by dense alignment to the previous
    keyframe (``frontend.dense.links``; local BA keeps that relative pose, vslam.backend.dense_links).
    """

    def __init__(self, cfg: FrontendConfig, K: np.ndarray, map_: Map, timers: dict[str, float]) -> None:
        self.cfg = cfg
        self.K = K
        self.map = map_
        self.timers = timers
        self.dense_links: dict[int, DenseLink] = {}
        self.rel: np.ndarray | None = None  # this frame's T_prev_cur when dense alignment posed it
        self._last_depth: tuple[np.ndarray, np.ndarray] | None = None  # (depth, T_world_cam) of the last tracked frame
        self._last_gray: np.ndarray | None = None
        self._last_tracked_kf: int | None = None  # keyframe id of the last tracked frame, None if not a keyframe
        self.n_bridged = 0
        self.n_refined = 0

    # ------------------------------------------------------------------ per frame
    def wants_keyframe(self) -> bool:
        """Posed by dense alignment to a keyframe: a keyframe keeps that link for local BA."""
        return self.rel is not None and self.cfg.dense.links and self._last_tracked_kf is not None

    def end_frame(self, frame: Frame, gray: np.ndarray, T_world_cam: np.ndarray | None, is_keyframe: bool,
                  kf_id: int | None) -> None:
        """Remember a tracked frame (its depth, grey image, pose, keyframe) for the next alignment
        and record the dense link of a keyframe posed by dense alignment."""
        if T_world_cam is not None and frame.depth is not None:
            if self.rel is not None and is_keyframe and self._last_tracked_kf is not None:
                self._add_link(frame, kf_id, self._last_tracked_kf, self.rel)
            self._last_tracked_kf = kf_id if is_keyframe else None
            self._last_depth = (frame.depth, T_world_cam.copy())
            self._last_gray = gray
        self.rel = None

    def _add_link(self, frame: Frame, kf_id: int | None, prev_kf_id: int, T_prev_cur: np.ndarray) -> None:
        if not self.cfg.dense.links or kf_id is None or kf_id == prev_kf_id:
            return
        uv, z = sample_depth_grid(frame.depth, self.K, max_depth=min(self.cfg.depth.max_depth, self.cfg.dense.max_depth))
        if len(z):
            self.dense_links[kf_id] = DenseLink(kf_id, prev_kf_id, T_prev_cur.copy(), uv, z)

    def _T_world_last_tracked(self, T_world_last_good: np.ndarray | None) -> np.ndarray:
        """The current pose of the last tracked frame: its keyframe's (moved by local BA / loop
        corrections since) when it became one, else as tracked and corrected."""
        kf = self.map.keyframes.get(self._last_tracked_kf) if self._last_tracked_kf is not None else None
        if kf is not None:
            return kf.T_world_cam
        return self._last_depth[1] if T_world_last_good is None else T_world_last_good

    # ------------------------------------------------------------------ alignments
    def bridge(self, frame: Frame, gray: np.ndarray, motion_model: MotionModel,
               T_world_last_good: np.ndarray | None) -> np.ndarray | None:
        """No pose from features: ``T_world_cam`` from aligning the depth to the last tracked
        frame's (from the motion prediction and from no motion), or None when refused. The tracker
        then makes the frame a keyframe of fresh depth points in the same map segment."""
        if (not self.cfg.dense.icp_fallback or self._last_depth is None or frame.depth is None
                or motion_model.T_world_last is None):
            return None
        t0 = time.perf_counter()
        T_world_prev = self._T_world_last_tracked(T_world_last_good)
        guesses = [inv_se3(T_world_prev) @ motion_model.predict(), np.eye(4)]
        T_prev_cur, agree = self._align(frame, gray, guesses, photometric=self.cfg.dense.icp_photometric)
        self.timers["pose"] += time.perf_counter() - t0
        if T_prev_cur is None:
            log.info("frame %d: depth ICP refused (%.2f of the depths agree)", frame.index, agree)
            return None
        self.rel = T_prev_cur
        self.n_bridged += 1
        log.info("frame %d: no feature pose, bridged by depth ICP (%.2f of the depths agree)", frame.index, agree)
        return T_world_prev @ T_prev_cur

    def refine(self, frame: Frame, gray: np.ndarray, T_world_cam: np.ndarray, motion_model: MotionModel,
               T_world_last_good: np.ndarray | None) -> np.ndarray:
        """A feature pose on few inliers (texture-poor views: the keypoints sit on object outlines,
        where the depth is ambiguous): refine the motion from the last tracked frame by dense
        alignment started at the feature pose; kept when the depths agree at least as well as at
        the feature pose."""
        if self._last_depth is None or self._last_gray is None or frame.depth is None or T_world_last_good is None:
            return T_world_cam
        t0 = time.perf_counter()
        depth_prev = self._last_depth[0]
        T_world_prev = self._T_world_last_tracked(T_world_last_good)
        T_guess = inv_se3(T_world_prev) @ T_world_cam
        agree0 = depth_agreement(np.nan_to_num(depth_prev), np.nan_to_num(frame.depth), self.K, T_guess,
                                 self.cfg.dense.agreement_step, self.cfg.dense.agreement_tolerance_m)
        guesses = [T_guess]
        if agree0 < self.cfg.dense.doubtful_agreement:  # a doubtful feature pose: also from the prediction and from no motion
            guesses += [inv_se3(T_world_prev) @ motion_model.predict(), np.eye(4)]
        T_prev_cur, agree = self._align(frame, gray, guesses, photometric=True)
        self.timers["pose"] += time.perf_counter() - t0
        if T_prev_cur is None or agree < agree0:
            return T_world_cam
        self.n_refined += 1
        self.rel = T_prev_cur
        log.debug("frame %d: feature pose refined by dense RGB-D alignment (depth agreement %.2f)", frame.index, agree)
        return T_world_prev @ T_prev_cur

    def _align(self, frame: Frame, gray: np.ndarray, guesses: list[np.ndarray],
               photometric: bool) -> tuple[np.ndarray | None, float]:
        """``(T_prev_cur, depth agreement)`` of the best-agreeing alignment over the initial
        ``guesses`` (``T_prev_cur``), or ``(None, best agreement)`` when none is accepted."""
        cfg = self.cfg
        depth_prev = self._last_depth[0]
        grays = (self._last_gray, gray) if photometric and self._last_gray is not None else (None, None)
        best, best_agree = None, 0.0
        for T_guess in guesses:
            T, agree = align_depth(depth_prev, frame.depth, self.K, T_guess, cfg.depth.min_depth,
                                   min(cfg.depth.max_depth, cfg.dense.max_depth), gray_prev=grays[0], gray_cur=grays[1],
                                   downsample=cfg.dense.refine_downsample if photometric else 1,
                                   min_agreement=cfg.dense.min_agreement, max_step_deg=cfg.dense.max_step_deg,
                                   max_step_m=cfg.dense.max_step_m, max_depth_diff=cfg.dense.icp_max_depth_diff,
                                   max_points_part=cfg.dense.icp_max_points_part, iterations=cfg.dense.icp_iterations,
                                   agreement_step=cfg.dense.agreement_step,
                                   agreement_tolerance_m=cfg.dense.agreement_tolerance_m)
            if T is not None and (best is None or agree > best_agree):
                best, best_agree = T, agree
            elif best is None:
                best_agree = max(best_agree, agree)
        return best, best_agree
