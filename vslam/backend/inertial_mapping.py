"""Visual-inertial initialization of a running map: when to try it, and applying it to the map.

The inertial sensors (``mono-inertial``, ``stereo-inertial``, ``rgbd-inertial``) map visually as
their base sensor until the window of keyframes is long enough (monocular: 2 s and 10 keyframes,
ORB-SLAM3's ``LocalMapping`` waits 2 s; stereo / RGB-D: 1 s and 10 keyframes). Then
:func:`vslam.backend.inertial_init.initialize_inertial` (inertial-only MAP, Campos et al. ICRA 2020)
runs on the keyframe poses of the current map segment, held fixed. A refusal (too little
excitation, a degenerate guess) is retried at the next keyframe.

On success the map is moved, once, by the similarity ``S = [s R_wg^T | 0]`` (visual world ->
gravity-aligned world, z up, metric; ``R_wg`` and ``s`` from the result): every keyframe pose
``T' = [R_wg^T R | s R_wg^T t]``, every point ``X' = s R_wg^T X``, normals rotated, the points'
distance bounds, depths and the culled keyframes' parent offsets scaled (``s = 1`` for stereo /
RGB-D). ``Map.loop_epoch`` is bumped so a local BA built before the move (realtime / parallel
modes) drops its stale result, as after a loop correction. The caller (the System) moves the
tracker and the trajectory recorded so far with the same ``S``.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, replace

import numpy as np

from vslam.backend.inertial_init import InertialInitConfig, InertialInitResult, initialize_inertial
from vslam.inertial import ImuBias, ImuCalibration, ImuMeasurements
from vslam.map.map import Map
from vslam.map.segment_merge import move_pose

log = logging.getLogger(__name__)

#: Seconds of keyframes before the first try: monocular (scale from the IMU needs motion) and others.
MIN_DURATION_MONO_S = 2.0
MIN_DURATION_S = 1.0
#: Full VI-BAs after the one right after the initialization, at these seconds from the first keyframe
#: of the initialization's window (ORB-SLAM3 ``LocalMapping``: its ``mTinit`` at 5 s and 15 s).
REFINE_AT_S = (5.0, 15.0)


@dataclass(frozen=True)
class InertialStart:
    """A successful initialization as applied: the result, the similarity ``S`` (visual world ->
    gravity-aligned world) and where it happened (``frame_index``, ``motion_s``: seconds from the
    first keyframe of the window to the frame)."""

    result: InertialInitResult
    S: np.ndarray
    frame_index: int
    motion_s: float


def alignment_similarity(result: InertialInitResult) -> np.ndarray:
    """``S = [s R_wg^T | 0]``, ``(4, 4)``: maps the visual world to the gravity-aligned metric world."""
    S = np.eye(4)
    S[:3, :3] = result.scale * result.R_world_gravityaligned.T
    return S


def move_map(slam_map: Map, S: np.ndarray) -> None:
    """Move the whole map by the similarity ``S = [s R | t]`` (module docstring). Call it under the map lock.
    A continued map (``vslam run --map`` of a gravity-aligned map): its loaded, gravity-aligned segments
    (:meth:`Map.segment_gravity_aligned`) stay; only the new session's segments and their points move."""
    S = np.asarray(S, float)
    s = float(np.cbrt(np.linalg.det(S[:3, :3])))
    R = S[:3, :3] / s
    aligned = {g: slam_map.segment_gravity_aligned(g) for g in {k.segment for k in slam_map.keyframes.values()}}
    kfs = [kf for kf in slam_map.keyframes.values() if not aligned[kf.segment]]
    store = slam_map.points
    rows = slice(0, len(store)) if len(kfs) == len(slam_map.keyframes) else slam_map.local_point_ids([k.id for k in kfs])
    store.position[rows] = store.position[rows] @ S[:3, :3].T + S[:3, 3]
    store.normal[rows] = store.normal[rows] @ R.T
    store.min_distance[rows] *= s
    store.max_distance[rows] *= s
    for kf in kfs:
        kf.T_world_cam = move_pose(S, kf.T_world_cam)
        if s != 1.0:
            if kf.depth is not None:
                kf.depth = kf.depth * s
            if "T_parent_kf" in kf.extra:
                kf.extra["T_parent_kf"] = kf.extra["T_parent_kf"].copy()
                kf.extra["T_parent_kf"][:3, 3] *= s
    slam_map.loop_epoch += 1


class InertialMapping:
    """Tries the visual-inertial initialization on the map's keyframes (module docstring).

    Args:
        imu: the IMU samples; calib: their calibration, ``T_imu_cam`` for the tracked camera
            (the rectified left camera for stereo).
        monocular: estimate the scale too (and wait :data:`MIN_DURATION_MONO_S`).
        config: settings of :func:`initialize_inertial`; its ``min_duration_s`` is raised to the
            sensor's wait (:data:`MIN_DURATION_MONO_S` / :data:`MIN_DURATION_S`) when lower.
    """

    def __init__(self, imu: ImuMeasurements, calib: ImuCalibration, monocular: bool,
                 config: InertialInitConfig | None = None) -> None:
        cfg = config or InertialInitConfig()
        wait = MIN_DURATION_MONO_S if monocular else MIN_DURATION_S
        self.config = replace(cfg, min_duration_s=max(cfg.min_duration_s, wait))
        self.imu = imu
        self.calib = calib
        self.monocular = monocular
        self.start: InertialStart | None = None
        self.attempts = 0
        self.last_reason = "not tried"
        self.refine_at_s = REFINE_AT_S
        self.from_map = False  # initialized by start_from_map (placed in a loaded gravity-aligned map)
        # full VI-BAs due so far (after the initialization, then at refine_at_s): ``stats.json``
        # ``imu_full_ba``; the backend's ``vi_ba_full`` lists those that ran (not with every backend mode)
        self.n_full_ba = 0

    @property
    def initialized(self) -> bool:
        return self.start is not None

    def window(self, slam_map: Map, segment: int) -> tuple[np.ndarray, np.ndarray]:
        """``(timestamps (K,), T_world_cam (K, 4, 4))`` of the segment's keyframes in time order."""
        kfs = sorted((k for k in slam_map.keyframes.values() if k.segment == segment and not k.bad),
                     key=lambda k: k.timestamp)
        if not kfs:
            return np.zeros(0), np.zeros((0, 4, 4))
        return np.array([k.timestamp for k in kfs]), np.stack([k.T_world_cam for k in kfs])

    def ready(self, timestamps: np.ndarray) -> bool:
        """Enough keyframes over a long enough time to try."""
        c = self.config
        return len(timestamps) >= c.min_keyframes and float(timestamps[-1] - timestamps[0]) >= c.min_duration_s

    def try_initialize(self, slam_map: Map, segment: int, frame_index: int,
                       timestamp: float) -> InertialStart | None:
        """Run the initialization on the segment's keyframes when ready; on success move the map
        (:func:`move_map`) and return what was applied, else None (retried on a later call)."""
        if self.initialized:
            return None
        t, T = self.window(slam_map, segment)
        if not self.ready(t):
            return None
        self.attempts += 1
        res = initialize_inertial(t, T, self.imu, self.calib, monocular=self.monocular, config=self.config)
        self.last_reason = res.reason
        if not res.success:
            log.info("IMU initialization at frame %d refused (%s); retrying at the next keyframe",
                     frame_index, res.reason)
            return None
        S = alignment_similarity(res)
        move_map(slam_map, S)
        self.start = InertialStart(res, S, frame_index, float(timestamp - t[0]))
        log.info("IMU initialized at frame %d after %.2f s of motion (%d keyframes): scale %.4f, gravity %s",
                 frame_index, self.start.motion_s, len(t), res.scale, np.round(res.gravity_world, 3))
        return self.start

    def start_from_map(self, frame_index: int, timestamp: float, bias: ImuBias) -> InertialStart:
        """The session was placed in a loaded gravity-aligned, metric map (``vslam run --map``): gravity
        (the world's -z) and scale (1) are the map's, the biases ``bias`` (the map keyframes'), the
        velocity comes from the tracked poses (the caller's :class:`ImuPredictor`). Nothing moves
        (``S`` is the identity), and no full VI-BA follows: the segment's keyframes are mostly the
        earlier session's, whose IMU samples this session does not have."""
        g = float(self.calib.gravity)
        res = InertialInitResult(success=True, reason="from the loaded map", R_world_gravityaligned=np.eye(3),
                                 scale=1.0, velocities=np.zeros((1, 3)), bias=bias, cost=0.0, initial_cost=0.0,
                                 gravity_world=np.array([0.0, 0.0, -g]), timestamps=np.array([float(timestamp)]),
                                 duration_s=0.0)
        self.start = InertialStart(res, np.eye(4), int(frame_index), 0.0)
        self.from_map = True
        self.refine_at_s = ()
        self.last_reason = res.reason
        log.info("IMU initialized from the loaded map at frame %d (its gravity and scale, biases %s / %s)",
                 frame_index, np.round(bias.gyro, 4), np.round(bias.accel, 3))
        return self.start

    def final_ba_due(self, sensor: str, backend_config) -> bool:
        """Whether a full VI-BA ends the run (``backend.final_inertial_ba``): once this run initialized
        the IMU itself (not from a loaded map, whose keyframes are another recording's), for the
        sensors whose local BA is visual-inertial. RGB-D keeps its visual local BA (module docstring of
        :mod:`vslam.backend.inertial_ba_mapping`), and a final VI-BA made the renderer's RGB-D + IMU
        sequence worse too (ATE 0.0180 -> 0.0208 m); mono and stereo gain on MH_01 (0.00280 ->
        0.00279, 0.00288 -> 0.00272 m)."""
        return self.initialized and not self.from_map and sensor != "rgbd" and backend_config.final_inertial_ba

    def refinement_due(self, timestamp: float) -> bool:
        """Whether the next full VI-BA of :attr:`refine_at_s` is due at ``timestamp`` (the caller runs
        it and counts it in :attr:`n_full_ba`)."""
        k = self.n_full_ba - 1  # the one after the initialization's is refinement 0
        if not self.initialized or not 0 <= k < len(self.refine_at_s):
            return False
        return timestamp - float(self.start.result.timestamps[0]) >= self.refine_at_s[k]

    def newest_keyframe(self, slam_map: Map, segment: int):
        """The segment's newest good keyframe (by time)."""
        return max((k for k in slam_map.keyframes.values() if k.segment == segment and not k.bad),
                   key=lambda k: k.timestamp)

    def store_states(self, slam_map: Map, segment: int) -> int:
        """Store the initialization's velocities and biases on the window's keyframes (the
        ``imu_velocity`` / ``imu_bias`` contract of :mod:`vslam.backend.inertial_ba_mapping`; the
        velocities are already in the gravity-aligned world). Returns how many."""
        from vslam.backend.inertial_ba_mapping import store_state

        res = self.start.result
        b = np.concatenate([res.bias.gyro, res.bias.accel])
        by_time = {float(t): k for k, t in enumerate(res.timestamps)}
        n = 0
        for kf in slam_map.keyframes.values():
            k = by_time.get(float(kf.timestamp))
            if kf.segment == segment and not kf.bad and k is not None:
                store_state(kf, res.velocities[k], b)
                n += 1
        return n

    def stats(self, final_bias=None) -> dict:
        """The ``imu_*`` entries of ``stats.json``; ``final_bias`` (an :class:`ImuBias`, the last
        estimate: tracking's) replaces the initialization's biases in ``imu_bias_*``, which are then
        also kept as ``imu_init_bias_*``."""
        out: dict = {"imu_initialized": self.initialized, "imu_init_attempts": self.attempts}
        if not self.initialized:
            out["imu_init_reason"] = self.last_reason
            return out
        st, res = self.start, self.start.result
        out.update({
            "imu_init_frame": st.frame_index,
            "imu_init_time_s": round(st.motion_s, 4),
            "gravity": [0.0, 0.0, -float(self.calib.gravity)],       # in the (z-up) world of the outputs
            "gravity_world": [float(x) for x in res.gravity_world],  # in the visual world before the move
            "imu_bias_gyro": [float(x) for x in res.bias.gyro],
            "imu_bias_accel": [float(x) for x in res.bias.accel],
            "imu_full_ba": self.n_full_ba,
            "imu_init_source": "map" if self.from_map else "estimated",
        })
        if final_bias is not None:
            out["imu_init_bias_gyro"], out["imu_init_bias_accel"] = out["imu_bias_gyro"], out["imu_bias_accel"]
            out["imu_bias_gyro"] = [float(x) for x in final_bias.gyro]
            out["imu_bias_accel"] = [float(x) for x in final_bias.accel]
        if self.monocular:
            out["imu_scale"] = float(res.scale)
        return out
