"""The SLAM system: wires features, frontend (tracking), map and (later) backend and loop closing.

A streaming object (the DPVO style): feed frames one by one with :meth:`System.track`, then ask
for :meth:`trajectory`, :meth:`keyframe_trajectory` and :meth:`stats`. Nothing reads ahead.

Example:
    >>> from vslam.system import System
    >>> system = System(config, camera, sensor="rgbd")          # doctest: +SKIP
    >>> for frame in dataset:                                    # doctest: +SKIP
    ...     result = system.track(frame)
    >>> system.finish(); traj = system.trajectory()              # doctest: +SKIP
"""
from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from vslam.datasets.frame import Frame
from vslam.trajectory import Trajectory
from vslam.features.config import FeatureConfig
from vslam.frontend.config import FrontendConfig
from vslam.geometry.lie import inv_se3
from vslam.frontend.tracker import Tracker
from vslam.geometry.camera import PinholeCamera
from vslam.map.keyframe import KeyFrame
from vslam.map.map import Map
from vslam.stream import warm_kernels

log = logging.getLogger(__name__)


@dataclass
class TrackResult:
    """Outcome of one :meth:`System.track` call."""

    frame_index: int
    timestamp: float
    T_world_cam: np.ndarray | None  # None when lost or still initializing
    state: str  # "ok" | "lost" | "initializing" | "imu" (inertial: posed by the IMU alone, vision failed)
    is_keyframe: bool
    n_inliers: int


class System:
    """Visual SLAM / odometry for one camera (``mono``, ``stereo`` or ``rgbd``), or visual-inertial
    (``mono-inertial``, ``stereo-inertial``, ``rgbd-inertial``: the visual part runs as the base sensor;
    the IMU is initialized on the map's keyframes, the world then gravity-aligned, z up, and metric,
    and it predicts each frame's pose; see :meth:`_inertial_step`).

    Args:
        config: the root :class:`vslam.config.Config` (its ``frontend`` and ``features`` fields are
            used), or a :class:`FrontendConfig`, or None for defaults.
        camera: intrinsics of the (left) images.
        sensor: ``mono``, ``stereo``, ``rgbd`` or one of them with ``-inertial``.
        features: a :class:`FeatureConfig` when ``config`` is not a root config.
        slam_map: a map to build on (see :meth:`from_map`); default a new, empty one.
        imu, imu_calibration: the IMU samples (:class:`vslam.inertial.ImuMeasurements`) and their
            calibration (``T_imu_cam`` of the tracked camera); required by the inertial sensors.
    """

    plots = True  # topology.png with the map outputs (vslam.api.run_path(plots=False) leaves it out)
    map_imu_start = None  # continuing a visual-inertial map: vslam.imu_from_map.MapImuStart (the API sets it)

    def __init__(self, config: Any = None, camera: PinholeCamera | None = None, sensor: str = "mono",
                 features: FeatureConfig | None = None, slam_map: Map | None = None,
                 imu: Any = None, imu_calibration: Any = None) -> None:
        if camera is None:
            from vslam.errors import CalibrationError

            raise CalibrationError("System needs the camera intrinsics (a PinholeCamera)")
        from vslam.inertial.sensors import split_sensor

        base_sensor, inertial = split_sensor(sensor)
        self._kernels_ms = warm_kernels()  # the compiled kernels loaded now, not in the first frames
        if isinstance(config, FrontendConfig):
            fcfg = config
        else:
            fcfg = getattr(config, "frontend", None) or FrontendConfig()
        feat = (features or getattr(config, "features", None) or FeatureConfig()).for_sensor(sensor)
        self.config = config
        self.frontend_config = fcfg
        self.feature_config = feat
        self.camera = camera
        self.sensor = sensor
        self.base_sensor = base_sensor
        sensor = base_sensor  # the stages see the visual sensor only
        self.map = slam_map if slam_map is not None else Map()
        self._kf_listeners: list[Callable[[KeyFrame], None]] = []
        self.tracker = Tracker(fcfg, feat, camera, sensor, self.map, on_keyframe=self._on_keyframe)
        self._init_backend(getattr(config, "backend", None), camera, sensor, feat, fcfg)
        if self.local_mapper is not None:  # RGB-D dense alignments as local-BA constraints (frontend.dense.links)
            self.local_mapper.dense_links = self.tracker.dense_links
        self._init_loop(getattr(config, "loop", None), camera, sensor, feat)
        self.inertial = None
        if inertial:
            self._init_inertial(imu, imu_calibration)
            if self.loop_closer is not None:  # joins with gravity-aligned segments wait for the IMU
                self.loop_closer.imu_pending = True
        # per tracked frame: timestamp, reference keyframe id or -1, T_world_cam as tracked, and the
        # reference keyframe's pose at that time (identity without one); see frame_poses
        self._timestamps: list[float] = []
        self._ref: list[int] = []
        self._T_rec: list[np.ndarray] = []
        self._T_ref_rec: list[np.ndarray] = []
        self._kf_inserted: dict[int, np.ndarray] = {}  # each keyframe's pose at insertion (frame_poses)
        self._n = {"frames": 0, "ok": 0, "lost": 0, "initializing": 0}
        self._imu_rows: list[list[float]] = []  # imu_states.csv (vslam.inertial.states_csv), from the IMU init on
        self._t_total = 0.0
        self._finished = False

    @classmethod
    def from_map(cls, config: Any, camera: PinholeCamera, sensor: str, slam_map: Map,
                 database: Any = None) -> "System":
        """Continue a saved map (``vslam run --map``; :func:`vslam.map.io.load_map` gives ``slam_map``
        and ``database``): the first frames are placed in it by global relocalization (bag of words
        + PnP, :meth:`Tracker.start_in_map`; ``frontend.tracking.max_frames_to_place`` tries, then a
        new segment starts), new keyframes and points join it, local BA and loop closing see the old
        keyframes, and every pose is in the loaded map's world frame. Needs loop closing
        (``loop.enabled``), whose database finds the places."""
        from vslam.errors import ConfigError

        system = cls(config, camera, sensor=sensor, slam_map=slam_map)
        if system.loop_closer is None:
            raise ConfigError("continuing a map needs loop.enabled (its keyframe database places the frames)")
        system.loop_closer.adopt_keyframes(database)
        system.tracker.start_in_map(system.frontend_config.tracking.max_frames_to_place)
        system.loaded_keyframes = len(slam_map.keyframes)
        return system

    # ------------------------------------------------------------------ hooks
    def add_keyframe_listener(self, callback: Callable[[KeyFrame], None]) -> None:
        """Call ``callback(keyframe)`` after every keyframe insertion (local BA plugs in here)."""
        self._kf_listeners.append(callback)

    def _on_keyframe(self, kf: KeyFrame) -> None:
        self._kf_inserted[kf.id] = kf.T_world_cam.copy()
        if self.inertial is not None and self.inertial.initialized:  # its IMU state: the tracker's at this frame
            self._store_tracked_state(kf)
        for cb in self._kf_listeners:
            cb(kf)

    # ------------------------------------------------------------------ backend (issue 5)
    def _init_backend(self, backend_cfg: Any, camera: PinholeCamera, sensor: str, feat: FeatureConfig,
                      fcfg: FrontendConfig) -> None:
        """``graph``: a :class:`LocalMapper` on the keyframe hook (new points, culling, local BA,
        final BA); ``ekf``: a :class:`FilterBackend` on every tracked pose. Without a graph backend
        (no root config, or ``ekf``) a minimal mapper still creates monocular points and culls
        (:class:`vslam.map.new_points.KeyframeMapping`)."""
        from vslam.backend.filter_backend import FilterBackend
        from vslam.backend.local_mapping import LocalMapper
        from vslam.frontend.keyframes import mapping_params
        from vslam.map.new_points import KeyframeMapping

        self._backend_cfg = backend_cfg
        self._map_lock = threading.RLock()  # tracking holds it; realtime local mapping takes it to edit the map
        self.local_mapper: LocalMapper | None = None
        self.filter_backend: FilterBackend | None = None
        params = mapping_params(fcfg, feat, camera.K)
        if backend_cfg is not None and backend_cfg.type != "ekf":
            mapper = LocalMapper
            if self.sensor != sensor:  # inertial sensors: a visual-inertial local BA once the IMU is initialized
                from vslam.backend.inertial_ba_mapping import InertialLocalMapper as mapper
            self.local_mapper = mapper(self.map, camera, sensor, backend_cfg, feat.scale_factor, self._map_lock,
                                       new_points=params)
            self.add_keyframe_listener(self.local_mapper.on_keyframe)
            self.local_mapper.correction_listeners.append(self._on_local_ba_correction)
            return
        self.add_keyframe_listener(KeyframeMapping(self.map, params).on_keyframe)
        if backend_cfg is not None:
            self.filter_backend = FilterBackend(backend_cfg.ekf, camera, self.map)

    def _on_local_ba_correction(self, kf_id: int, T_world_kf_before: np.ndarray, T_world_kf_after: np.ndarray) -> None:
        """Local BA moved the newest keyframe: move the tracker's last poses with it (as for loops)."""
        self._on_loop_correction(kf_id, T_world_kf_before, T_world_kf_after)

    # ------------------------------------------------------------------ loop closing (issue 6)
    def _init_loop(self, loop_cfg: Any, camera: PinholeCamera, sensor: str, feat: FeatureConfig) -> None:
        """A :class:`LoopCloser` on the keyframe hook (``loop.enabled``) and a :class:`Relocalizer`
        sharing its keyframe database (``self.relocalizer(obs)``, for the tracker when lost)."""
        self.loop_closer = None
        self.relocalizer = None
        if loop_cfg is None or not loop_cfg.enabled:
            return
        from vslam.loop.closing import LoopCloser
        from vslam.loop.relocalization import Relocalizer

        gba = self.local_mapper.global_ba if self.local_mapper is not None else None
        pg = getattr(self._backend_cfg, "pose_graph", None)
        self.loop_closer = LoopCloser(self.map, camera, sensor, loop_cfg, scale_factor=feat.scale_factor,
                                      lock=self._map_lock, global_ba=gba, pose_graph=pg,
                                      realtime=getattr(self._backend_cfg, "mode", "deterministic") == "realtime")
        self.loop_closer.correction_listeners.append(self._on_loop_correction)
        lm = self.local_mapper
        if lm is not None and lm.config.mode == "parallel" and lm.config.local_ba:
            # parallel local BA: a keyframe reaches loop closing once its local BA is in the map (as in
            # deterministic mode, where loop closing runs after local mapping in the same frame)
            lm.settled_listeners.append(self._loop_after_local_mapping)
        else:
            self.add_keyframe_listener(self.loop_closer.on_keyframe)
        self.relocalizer = Relocalizer(self.map, camera, sensor, self.loop_closer.vocabulary, self.loop_closer.database,
                                       loop_cfg.relocalization, feat.scale_factor, self.loop_closer.bf)
        self.tracker.set_relocalizer(self.relocalizer)
        self.loop_closer.merge_listeners.append(self.tracker.segment_merged)  # segments joined (several segments)
        if self.local_mapper is not None:
            self.loop_closer.local_ba = self.local_mapper.process

    def _loop_after_local_mapping(self, kf: KeyFrame) -> None:
        self.loop_closer.on_keyframe(kf)
        self.loop_closer.after_frame()

    def _on_loop_correction(self, kf_id: int, T_world_kf_before: np.ndarray, T_world_kf_after: np.ndarray) -> None:
        """The current keyframe moved: move the tracker's last poses with it (motion-model prediction)."""
        self.tracker.apply_correction(T_world_kf_after @ inv_se3(T_world_kf_before))

    # ------------------------------------------------------------------ inertial (issue 28)
    def _init_inertial(self, imu: Any, imu_calibration: Any) -> None:
        """The IMU initialization on the keyframes (:class:`vslam.backend.inertial_mapping.InertialMapping`);
        the local mapper's BA becomes visual-inertial once it succeeds
        (:class:`vslam.backend.inertial_ba_mapping.InertialLocalMapper`)."""
        from vslam.backend.inertial_mapping import InertialMapping
        from vslam.errors import DatasetError

        if imu is None or imu_calibration is None:
            missing = " and ".join(n for n, v in (("IMU samples", imu), ("IMU calibration", imu_calibration)) if v is None)
            raise DatasetError(f"sensor {self.sensor} needs {missing}: a dataset with an IMU (EuRoC imu0/) or --imu FILE")
        self.inertial = InertialMapping(imu, imu_calibration, monocular=self.base_sensor == "mono")
        if hasattr(self.local_mapper, "state_listeners"):
            self.local_mapper.inertial = self.inertial
            self.local_mapper.state_listeners.append(self._on_imu_states)

    def _inertial_step(self, frame: Frame, out: Any) -> np.ndarray | None:
        """After a keyframe, until the IMU is initialized: try it on the map's keyframes; on success the
        map was moved by ``S`` (gravity-aligned z-up world, metric scale); move the tracker, the
        trajectory recorded so far and the keyframes' insertion poses with it, store the keyframes'
        velocities and biases, run a full VI-BA, and start the IMU prediction from the newest keyframe's
        state. Later keyframes: the full VI-BA again at :data:`~vslam.backend.inertial_mapping.REFINE_AT_S`.
        Placed in a loaded visual-inertial map: the IMU starts from it (:mod:`vslam.imu_from_map`).
        Returns ``S`` when the map moved now, else None."""
        from vslam.map.segment_merge import move_pose

        im = self.inertial
        if self.map_imu_start is not None and not im.initialized and self.map_imu_start.applies():
            if out.state == "ok":
                self.map_imu_start.step(frame, out.T_world_cam)
            return None
        if not out.is_keyframe or out.state != "ok":
            return None
        if im.initialized:
            if im.refinement_due(frame.timestamp):
                self._full_inertial_ba()
            return None
        with self._map_lock:
            start = im.try_initialize(self.map, self.tracker.segment, frame.index, frame.timestamp)
            if start is None:
                return None
            if self.loop_closer is not None:
                self.loop_closer.imu_pending = False
            S = start.S
            self.tracker.move_world(S)
            self._T_rec = [move_pose(S, T) for T in self._T_rec]
            self._T_ref_rec = [move_pose(S, T) if r >= 0 else T for T, r in zip(self._T_ref_rec, self._ref)]
            self._kf_inserted = {k: move_pose(S, T) for k, T in self._kf_inserted.items()}
            self.map.gravity_aligned = True
            im.store_states(self.map, self.tracker.segment)
        self._full_inertial_ba()
        from vslam.backend.inertial_ba_mapping import keyframe_state
        from vslam.imu_from_map import tracker_predictor
        from vslam.inertial import ImuBias

        with self._map_lock:
            kf = im.newest_keyframe(self.map, self.tracker.segment)
            res = start.result
            v, b = keyframe_state(kf) or (res.velocities[-1], np.r_[res.bias.gyro, res.bias.accel])
            self.tracker.set_imu_predictor(tracker_predictor(self, ImuBias(b[:3], b[3:]), kf.timestamp, kf.T_world_cam, v))
        return S

    def _full_inertial_ba(self) -> None:
        """A full VI-BA of the current segment (graph backend with the inertial mapper), counted."""
        if hasattr(self.local_mapper, "full_inertial_ba"):
            self.local_mapper.full_inertial_ba(self.tracker.segment, self.inertial.monocular)
        self.inertial.n_full_ba += 1

    def _store_tracked_state(self, kf: KeyFrame) -> None:
        from vslam.backend.inertial_ba_mapping import store_state

        if (state := self.tracker.imu_state(kf.timestamp)) is not None:
            store_state(kf, *state)

    def _on_imu_states(self, kf_ids: list[int]) -> None:
        """A VI-BA estimated these keyframes' states: the predictor takes the newest's velocity and biases."""
        p = self.tracker.imu_predictor
        kfs = [self.map.keyframes[k] for k in kf_ids if k in self.map.keyframes]
        if p is not None and p.active and kfs:
            kf = max(kfs, key=lambda k: k.timestamp)
            p.adopt_keyframe(kf.timestamp, kf.T_world_cam, kf.extra["imu_velocity"], kf.extra["imu_bias"])

    # ------------------------------------------------------------------ streaming
    def prepare(self, frame: Frame) -> None:
        """Optional, from another thread ahead of :meth:`track`: the work on ``frame`` that needs no
        tracking state (grayscale, feature detection); see :meth:`Tracker.prepare`. The runner's
        decoding thread calls it so that detection overlaps tracking on a second core."""
        self.tracker.prepare(frame)

    def frame_preparer(self):
        """A picklable callable doing :meth:`prepare`'s work, for a prefetch *process*
        (:func:`vslam.datasets.prefetch.prefetch_process`): ``preparer(frame) -> result``; hand
        ``result`` back with :meth:`adopt_prepared` before :meth:`track` gets that frame."""
        return self.tracker.preparer()

    def adopt_prepared(self, frame: Frame, result, seconds: float = 0.0) -> None:
        """Take a :meth:`frame_preparer` result computed in another process for ``frame``."""
        gray, feats = result
        self.tracker.adopt_prepared(frame, gray, feats, seconds)

    def track(self, frame: Frame) -> TrackResult:
        """Track one frame; returns its pose (None when lost or initializing)."""
        with self._map_lock:
            t0 = time.perf_counter()
            out = self.tracker.track(frame)
            self._t_total += time.perf_counter() - t0
            self._n["frames"] += 1
            self._n[out.state] = self._n.get(out.state, 0) + 1
            for ts, T in out.backfill:  # frames before a monocular initialization, posed afterwards
                self._record(ts, T, None)
            T_out = out.T_world_cam
            if self.filter_backend is not None:  # EKF backend: the filtered pose replaces the measured one
                T_out = self.filter_backend.filter(frame.timestamp, T_out, out.n_inliers, out.ref_keyframe)
            if T_out is not None:
                self._record(frame.timestamp, T_out, out.ref_keyframe)
            if out.is_keyframe:
                self._color_new_points(frame)
        if self.local_mapper is not None:  # deterministic local BA runs here, after the frame is recorded
            self.local_mapper.after_frame()
        if self.loop_closer is not None:  # deterministic loop closing, after local mapping
            self.loop_closer.after_frame()
        if self.inertial is not None:
            S = self._inertial_step(frame, out)
            if S is not None and T_out is not None:  # this frame's pose in the gravity-aligned world too
                from vslam.map.segment_merge import move_pose

                T_out = move_pose(S, T_out)
            if T_out is not None:
                self._record_imu_state(frame.timestamp, out.state == "imu")
        return TrackResult(frame.index, frame.timestamp, T_out, out.state, out.is_keyframe, out.n_inliers)

    def _record_imu_state(self, timestamp: float, imu_only: bool) -> None:
        """A row of ``imu_states.csv``: the IMU velocity at this frame and the biases (once predicting)."""
        p = self.tracker.imu_predictor
        if p is not None and p.active and (v := p.velocity_at(timestamp)) is not None:
            self._imu_rows.append([timestamp, *v, *p.bias.gyro, *p.bias.accel, int(imu_only)])

    def save_map_outputs(self, directory: str | Path, metadata: dict | None = None, progress: Any = None) -> dict:
        """Write the sparse map (``sparse.ply``), the topological map (``topology.json``/``.png``; the PNG
        unless ``plots`` was set False) and the reloadable map (``map/``, with the bag-of-words database).
        ``progress``: an optional tqdm-like bar, advanced once per file written."""
        from vslam.reconstruction.map_outputs import write_map_outputs

        lc = self.loop_closer
        loops_kf = [(r.query_kf, r.match_kf, r.inliers) for r in lc.loops] if lc is not None else []
        with self._map_lock:
            written = write_map_outputs(directory, self.map, camera=self.camera, database=lc.database if lc else None,
                                        loops_kf=loops_kf, metadata={"sensor": self.sensor, **(metadata or {})},
                                        progress=progress, plots=self.plots)
        if self._imu_rows:  # inertial runs: the velocity and biases per frame (vslam report plots them)
            from vslam.inertial.states_csv import write_imu_states

            written["imu_states"] = str(write_imu_states(Path(directory) / "imu_states.csv", self._imu_rows))
        return written

    def _color_new_points(self, frame: Frame) -> None:
        """Give the newest keyframe's not yet coloured map points the colour of this frame's image
        at their keypoints (RGB; grey images give grey points). For the sparse map export."""
        if not self.map.keyframes:
            return
        kf = self.map.keyframes[max(self.map.keyframes)]
        idx = np.flatnonzero(kf.point_ids >= 0)
        if not len(idx):
            return
        pid = kf.point_ids[idx]
        store = self.map.points
        todo = ~store.color[pid].any(axis=1)
        if not todo.any():
            return
        idx, pid = idx[todo], pid[todo]
        h, w = frame.image.shape[:2]
        u = np.clip(np.rint(kf.uv[idx, 0]).astype(int), 0, w - 1)
        v = np.clip(np.rint(kf.uv[idx, 1]).astype(int), 0, h - 1)
        pix = frame.image[v, u]
        store.color[pid] = pix[:, ::-1] if pix.ndim == 2 else np.repeat(pix[:, None], 3, axis=1)

    def _record(self, timestamp: float, T_world_cam: np.ndarray, ref_kf: int | None) -> None:
        kf = self.map.keyframes.get(ref_kf) if ref_kf is not None else None
        if kf is not None:
            self._ref.append(kf.id)
            self._T_ref_rec.append(kf.T_world_cam.copy())
        else:
            self._ref.append(-1)
            self._T_ref_rec.append(np.eye(4))
        self._T_rec.append(T_world_cam.copy())
        self._timestamps.append(timestamp)

    def finish(self) -> None:
        """End of input: flush pending local mapping, then the optional global BA (``backend.final_ba``) and
        the full VI-BA of an inertial run (``backend.final_inertial_ba``)."""
        if self._finished:
            return
        if self.local_mapper is not None:
            self.local_mapper.finish()
        if self.loop_closer is not None:
            self.loop_closer.finish()
        if self.local_mapper is not None:
            if self._backend_cfg.final_ba:
                self.local_mapper.global_ba()
            if self.inertial is not None and self.inertial.final_ba_due(self.base_sensor, self._backend_cfg):
                self._full_inertial_ba()
        self._finished = True

    # ------------------------------------------------------------------ results
    def trajectory(self) -> Trajectory:
        """Every tracked frame, with its pose re-expressed through its reference keyframe's
        current (possibly optimized) pose: ``T_world_cam = T_world_kf @ T_kf_cam``, or with the
        corrections of the keyframes before and after it blended (``backend.frame_correction``,
        :func:`vslam.backend.frame_poses.frame_poses`)."""
        from vslam.backend.frame_poses import frame_poses

        if not self._timestamps:
            return Trajectory(np.zeros(0), np.zeros((0, 4, 4)))
        mode = getattr(self._backend_cfg, "frame_correction", "reference")
        ts = np.asarray(self._timestamps)
        T = frame_poses(ts, np.asarray(self._ref), np.stack(self._T_rec), np.stack(self._T_ref_rec), self.map.keyframes,
                        self._kf_inserted, interpolate=mode == "interpolate")
        order = np.argsort(ts, kind="stable")
        ts, T = ts[order], T[order]
        keep = np.ones(len(ts), bool)
        keep[1:] = np.diff(ts) > 0
        return Trajectory(ts[keep], T[keep])

    def keyframe_trajectory(self) -> Trajectory:
        kfs = sorted(self.map.keyframes.values(), key=lambda k: k.timestamp)
        ts = np.array([k.timestamp for k in kfs])
        keep = np.r_[True, np.diff(ts) > 0] if kfs else np.zeros(0, bool)
        return Trajectory(ts[keep], np.stack([k.T_world_cam for k in kfs])[keep] if kfs else np.zeros((0, 4, 4)))

    def _loaded_map_stats(self) -> dict:
        """Continuing a loaded map (:meth:`from_map`): its folder (``map_loaded``, set by the caller), its
        keyframes, the frame first placed in it (``placed_at_frame``; None: the session started its own
        segment), the map keyframe it was placed against and the inliers."""
        if getattr(self, "loaded_keyframes", None) is None:
            return {}
        placed = self.tracker.placed
        return {"map_loaded": getattr(self, "map_loaded", None), "map_keyframes_loaded": self.loaded_keyframes,
                "placed_at_frame": placed[0] if placed else None,
                "placed_keyframe": placed[1] if placed else None, "placed_inliers": placed[2] if placed else None}

    def stats(self) -> dict:
        n = max(self._n["frames"], 1)
        stage_ms = {k: round(1000.0 * v / n, 3) for k, v in self.tracker.timers.items()}
        stage_ms["total"] = round(1000.0 * self._t_total / n, 3)
        backend: dict = {"type": "none"}
        if self.local_mapper is not None:
            backend = {"type": "graph", **self.local_mapper.stats()}
            stage_ms["local_ba"] = backend["local_ba_ms_mean"]  # mean ms per local BA call (not per frame)
        elif self.filter_backend is not None:
            backend = self.filter_backend.stats()
        inertial = {} if self.inertial is None else {
            **self.inertial.stats(getattr(self.tracker.imu_predictor, "bias", None)),
            "imu_predicted_frames": getattr(self.tracker.imu_predictor, "n_predicted", 0),
            "imu_only_frames": self.tracker.n_imu_only}
        return {
            **inertial,
            "keyframes": self.map.n_keyframes,
            "map_points": self.map.n_points,
            "loops": self.loop_closer.loop_list() if self.loop_closer is not None else [],
            "frames_ok": self._n.get("ok", 0),
            "frames_lost": self._n.get("lost", 0),
            "frames_initializing": self._n.get("initializing", 0),
            "map_segments": self.tracker.segment + 1,  # segments started (joins do not lower it)
            "segments": len({k.segment for k in self.map.keyframes.values()}),
            "merges": [m.to_json() for m in self.loop_closer.merges] if self.loop_closer is not None else [],
            **self._loaded_map_stats(),
            "relocalizations": self.tracker.n_relocalized,
            "depth_bridged": self.tracker.n_depth_bridged,
            "depth_refined": self.tracker.n_depth_refined,
            "stage_ms": stage_ms,
            # loading the compiled kernels (vslam.stream) and the loop closer's pose-graph solver
            "startup_ms": {"kernels": self._kernels_ms,
                           **(self.loop_closer.startup_ms if self.loop_closer is not None else {})},
            "sensor": self.sensor,
            "association": self.frontend_config.association,
            "motion": self.frontend_config.motion,
            "backend": backend,
            "loop_closing": self.loop_closer.stats() if self.loop_closer is not None else {"enabled": False},
        }
