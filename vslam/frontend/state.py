"""What the tracker carries from one frame to the next (:class:`TrackingState`) and what it
reports per frame (:class:`TrackOutput`)."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from vslam.frontend.motion_model import MotionModel
from vslam.frontend.observation import Observation
from vslam.geometry.lie import se3_exp, se3_log


@dataclass
class TrackOutput:
    """What :meth:`vslam.frontend.tracker.Tracker.track` reports for one frame."""

    T_world_cam: np.ndarray | None
    state: str  # "ok" | "lost" | "initializing" | "imu" (posed by the IMU alone)
    is_keyframe: bool
    n_inliers: int
    ref_keyframe: int | None = None
    backfill: list[tuple[float, np.ndarray]] = field(default_factory=list)  # (timestamp, T_world_cam) of earlier frames


@dataclass
class TrackingState:
    """The tracker's memory between frames (ORB-SLAM's mLastFrame, mpReferenceKF, mVelocity, ...).

    Attributes:
        status: ``initializing`` (no map segment yet), ``ok`` or ``lost``.
        prev, prev_gray: the previous frame's observation and grey image (KLT tracks start there).
        ref_kf, last_kf: the reference keyframe (local map centre) and the newest keyframe.
        frames_since_kf: frames tracked since the last keyframe.
        kf_ref_tracked: map points tracked by the first frame after the reference keyframe.
        kf_ref_floor: with ``keyframes.revisit_floor_mono``, the highest ``kf_ref_tracked`` since
            the last keyframe: a revisit's new reference restarts the count, never below it (else
            a slow decay over reference switches never made a keyframe).
        segment: index of the current map segment (-1 before the first).
        n_lost_run: consecutive lost frames.
        T_world_last_good: pose of the last tracked frame (the origin of a re-initialized segment).
        speed_per_frame: distance of the last tracked step (scales a re-initialized monocular segment).
        motion_model: constant-velocity prediction.
        local_ids: cached map point ids of the local map (None: recompute).
        revisiting: the reference is an old keyframe the frame revisits (until the next keyframe).
    """

    status: str = "initializing"
    prev: Observation | None = None
    prev_gray: np.ndarray | None = None
    ref_kf: int | None = None
    last_kf: int | None = None
    frames_since_kf: int = 0
    kf_ref_tracked: int | None = None
    kf_ref_floor: int = 0
    segment: int = -1
    n_lost_run: int = 0
    T_world_last_good: np.ndarray | None = None
    speed_per_frame: float = 0.0
    motion_model: MotionModel = field(default_factory=MotionModel)
    local_ids: np.ndarray | None = None
    revisiting: bool = False

    def origin(self) -> np.ndarray:
        """Where a new map segment starts: the last good pose, or the identity."""
        return np.eye(4) if self.T_world_last_good is None else self.T_world_last_good.copy()

    def set_prev(self, obs: Observation, gray: np.ndarray) -> None:
        self.prev = obs
        self.prev_gray = gray

    def start(self, T_world_cam: np.ndarray, T_world_prev: np.ndarray | None = None, gap: int = 1) -> None:
        """A map segment starts at ``T_world_cam``; with ``T_world_prev`` (monocular: the reference
        frame ``gap`` frames earlier) the motion model gets the per-frame velocity between them."""
        self.status = "ok"
        self.n_lost_run = 0
        mm = self.motion_model
        mm.reset(T_world_prev)
        mm.update(T_world_cam)
        if T_world_prev is not None and gap > 1:
            mm.T_last_cur = se3_exp(se3_log(mm.T_last_cur) / gap)
        self.T_world_last_good = T_world_cam.copy()

    def tracked(self, T_world_cam: np.ndarray, obs: Observation, gray: np.ndarray, speed: bool = True) -> None:
        """The frame got a pose: update the speed (unless ``speed`` is False), the motion model
        and the last good pose."""
        self.status = "ok"
        self.n_lost_run = 0
        if speed and self.T_world_last_good is not None:
            self.speed_per_frame = float(np.linalg.norm(T_world_cam[:3, 3] - self.T_world_last_good[:3, 3]))
        self.motion_model.update(T_world_cam)
        self.T_world_last_good = T_world_cam.copy()
        self.set_prev(obs, gray)

    def count_reference(self, n_tracked: int) -> None:
        """The first frame after the reference keyframe (or after a revisit's switch) sets
        ``kf_ref_tracked`` to the map points it tracked, never below ``kf_ref_floor``."""
        if self.frames_since_kf == 1 or self.kf_ref_tracked is None:
            self.kf_ref_tracked = max(int(n_tracked), self.kf_ref_floor)

    def revisit(self, kf_id: int, keep_floor: bool = False) -> None:
        """A revisit: the old keyframe ``kf_id`` becomes the reference; the next frame's count
        restarts the tracked-points ratio. With ``keep_floor`` (``keyframes.revisit_floor_mono``)
        it restarts from no less than the highest count since the last keyframe, so a slow loss of
        tracked points across reference switches still makes a keyframe before the map is lost
        (depth sensors have the close-points rule for that, and keep a lap over a mapped place
        free of keyframes)."""
        self.ref_kf = kf_id
        self.local_ids = None
        if keep_floor:
            self.kf_ref_floor = max(self.kf_ref_floor, self.kf_ref_tracked or 0)
        self.kf_ref_tracked = None
        self.revisiting = True

    def keyframe_inserted(self, kf_id: int) -> None:
        self.ref_kf = kf_id
        self.last_kf = kf_id
        self.local_ids = None
        self.frames_since_kf = 0
        self.kf_ref_tracked = None
        self.kf_ref_floor = 0
        self.revisiting = False

    def apply_correction(self, D: np.ndarray) -> None:
        """The map moved by ``D = T_world_new_from_old`` (local BA or a loop correction moved the
        newest keyframe): move the last poses with it, so the next prediction lands in the
        corrected map (ORB-SLAM's UpdateLastFrame)."""
        mm = self.motion_model
        if mm.T_world_last is not None:
            mm.T_world_last = D @ mm.T_world_last
        if self.T_world_last_good is not None:
            self.T_world_last_good = D @ self.T_world_last_good
