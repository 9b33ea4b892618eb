"""The high-level Python API: open a sequence, run SLAM on it, evaluate.

Example::

    from vslam.api import run_path
    result = run_path("path/to/tum_sequence", "out/", sensor="rgbd")
    print(result.stats["ate_rmse"])

Streaming use, frame by frame::

    from vslam.config import Config, with_depth_noise
    from vslam.datasets import open_dataset
    from vslam.system import System
    ds = open_dataset("path/to/sequence", sensor="rgbd")
    cfg = with_depth_noise(Config(), ds.depth_disparity_sigma_px)  # the dataset's depth weight, as run_path
    system = System(cfg, ds.camera, sensor="rgbd")
    for frame in ds:
        result = system.track(frame)       # result.T_world_cam is None when lost
"""
from __future__ import annotations

import logging
from pathlib import Path

from vslam.config import load_config, with_depth_noise
from vslam.errors import DatasetError

log = logging.getLogger(__name__)


def choose_sensor(available: tuple[str, ...] | list[str], requested: str | None) -> str:
    """The requested sensor if the data supports it; by default RGB-D, else stereo, else mono."""
    if requested is not None:
        if requested not in available:
            raise DatasetError(
                f"this sequence provides {', '.join(available)}; it cannot be run as {requested!r}"
            )
        return requested
    for s in ("rgbd", "stereo", "mono"):
        if s in available:
            return s
    raise DatasetError("this sequence provides no usable sensor")


def resolve_config(config: str | Path | object | None, overrides) -> object:
    """The root :class:`Config` from a YAML path (or None: defaults) plus ``overrides``, or a given
    Config object, with ``overrides`` applied on top when there are any."""
    from vslam.config import Config

    if isinstance(config, (str, Path)):
        _refuse_calibration_as_config(Path(config))
    if config is None or isinstance(config, (str, Path)):
        return load_config(Config, config, overrides)
    return load_config(Config, None, overrides) if overrides else config


def _refuse_calibration_as_config(path: Path) -> None:
    """A camera calibration (ORB-SLAM settings, OpenCV, Kalibr ...) passed as ``--config`` is a
    common mistake: say so and point to ``--camera``."""
    from vslam.datasets.calibration import FORMAT_NAMES, detect_camera_format
    from vslam.errors import ConfigError

    if not path.is_file() or path.suffix.lower() not in (".yaml", ".yml"):
        return
    try:
        from vslam.datasets.camera_yaml import load_yaml as _load_yaml

        data = _load_yaml(path)
    except DatasetError:
        return
    fmt = detect_camera_format(data)
    if fmt is not None:
        raise ConfigError(
            f"{path}: this is a camera calibration ({FORMAT_NAMES[fmt]}), not a vslam settings file; "
            f"pass it as --camera {path}"
        )


def open_sequence(path: str | Path, dataset: str | None, sensor: str | None, start_frame: int,
                  max_frames: int | None, preferred_sensor: str | None = None, camera=None,
                  options: dict | None = None):
    """Open the sequence at ``path`` for ``sensor`` (default: ``preferred_sensor`` when the data has
    it, else :func:`choose_sensor`'s) and check the frame range.

    Returns ``(dataset, sensor, stop)``: frames ``start_frame .. stop - 1`` are to be used.
    Raises :class:`DatasetError` when ``start_frame`` is outside the sequence.
    """
    from vslam.datasets import open_dataset

    options = options or {}
    if preferred_sensor:  # a map of an inertial run: its images are read as the base sensor's
        preferred_sensor = preferred_sensor.removesuffix("-inertial")
    probe = open_dataset(path, kind=dataset, camera=camera, **options)
    if sensor is None and preferred_sensor in probe.sensors:
        sensor = preferred_sensor
    sensor = choose_sensor(probe.sensors, sensor)
    ds = probe if sensor == probe.sensor else open_dataset(path, kind=dataset, sensor=sensor, camera=camera, **options)
    n = len(ds)
    if start_frame < 0 or start_frame >= n:
        raise DatasetError(f"--start-frame {start_frame} is outside the sequence (0..{n - 1})")
    if max_frames is not None and max_frames < 1:
        raise DatasetError(f"--max-frames must be at least 1, got {max_frames}")
    stop = n if max_frames is None else min(n, start_frame + max_frames)
    return ds, sensor, stop


def progress_bar(enabled: bool = True):
    """A tqdm factory writing to stderr for the library's ``progress=`` arguments, or None when
    ``enabled`` is false or stderr is not a terminal (logs and pipes get no bars)."""
    import functools
    import sys

    if not enabled or not sys.stderr.isatty():
        return None
    from tqdm import tqdm

    return functools.partial(tqdm, file=sys.stderr, leave=False, dynamic_ncols=True)


TRAJECTORY_FORMATS = ("tum", "kitti", "euroc")


def export_trajectory(out_dir: Path, trajectory, fmt: str) -> Path:
    """Write ``trajectory`` beside the run folder's TUM ``trajectory.txt`` in another format:
    ``trajectory_kitti.txt`` (+ ``trajectory_kitti_times.txt``) or ``trajectory_euroc.csv``."""
    from vslam.trajectory import write_trajectory

    if fmt not in TRAJECTORY_FORMATS:
        raise DatasetError(f"unknown trajectory format {fmt!r}; use one of {', '.join(TRAJECTORY_FORMATS)}")
    if fmt == "kitti":
        path = out_dir / "trajectory_kitti.txt"
        write_trajectory(path, trajectory, "kitti", out_dir / "trajectory_kitti_times.txt")
    else:
        path = out_dir / "trajectory_euroc.csv"
        write_trajectory(path, trajectory, "euroc")
    return path


def run_path(
    path: str | Path,
    output: str | Path | None,
    sensor: str | None = None,
    dataset: str | None = None,
    config: str | Path | object | None = None,
    overrides: list[str] | tuple[str, ...] = (),
    max_frames: int | None = None,
    start_frame: int = 0,
    progress: bool = False,
    viz: str | None = None,
    dense: bool = False,
    prefetch: str = "auto",
    camera: str | Path | None = None,
    trajectory_format: str = "tum",
    topics: str | None = None,
    viz_options: dict | None = None,
    map_dir: str | Path | None = None,
    gt: str | Path | None = None,
    imu: str | Path | None = None,
    plots: bool = True,
):
    """Run SLAM over the sequence at ``path`` and (if ``output``) write the run folder.

    ``sensor``: ``mono``, ``stereo``, ``rgbd`` or one of them with ``-inertial``; ``imu``: an IMU
    file for a sequence without one (:func:`_open_run`).

    ``map_dir`` (a run folder, or its ``map/``) continues that saved map (:meth:`System.from_map`):
    the output map is the extended one and the trajectory is in its world frame.

    ``dense`` also fuses the keyframes into a TSDF mesh (``mesh.ply``, ``dense.ply``; RGB-D or
    stereo, needs the ``dense`` extra). ``viz`` streams to a rerun viewer (``"rerun"``) or records a file (``"rerun:FILE.rrd"``);
    ``viz_options`` go to :class:`vslam.viz.rerun_viewer.RerunViewer` (``image_scale``, ``image_every``).
    ``prefetch`` (``auto``, ``thread``, ``process``, ``none``) is where frames are decoded and
    features detected ahead of tracking (see :func:`vslam.runner.run_sequence`); ``auto`` uses a
    child process on long runs when that is safe (a script calling this should guard its work
    with ``if __name__ == "__main__":``, as any program using multiprocessing must). The poses do
    not depend on it.
    ``camera`` is a calibration file in any format :mod:`vslam.datasets.calibration` reads (or a
    TUM preset name ``fr1``/``fr2``/``fr3``), overriding the sequence's own calibration.
    ``trajectory_format`` (``kitti``, ``euroc``) also writes the trajectory in that format.
    ``topics`` (``COLOR[,DEPTH|,RIGHT]``) picks the image topics of a ROS bag.
    ``gt`` chooses the ground truth: None the dataset's own, ``"none"`` none, else a trajectory
    file (:func:`vslam.datasets.ground_truth.resolve_ground_truth`: a problem with it skips the
    evaluation with a warning; ``stats`` names it, ``gt_file`` and ``gt_frame``).
    ``plots=False`` leaves out ``trajectory.png`` and ``topology.png`` (``vslam map``'s sessions).
    Returns a :class:`vslam.runner.RunResult` (``stats`` dict and final ``trajectory``).
    """
    from vslam.datasets.ground_truth import resolve_ground_truth
    from vslam.datasets.prefetch import FrameRange
    from vslam.runner import run_sequence
    from vslam.system import System

    if _is_live(dataset, path, dense, start_frame):
        return run_live(path, output, camera=camera, config=config, overrides=overrides, max_frames=max_frames,
                        progress=progress, viz=viz, trajectory_format=trajectory_format, viz_options=viz_options)
    cfg = resolve_config(config, overrides)
    ds, sensor, stop, imu_inputs = _open_run(path, dataset, sensor, imu, map_dir, dense, start_frame, max_frames,
                                             camera, topics)
    truth = resolve_ground_truth(ds, gt, (start_frame, stop))  # before the tracker is built: a --gt typo fails
    cfg = with_depth_noise(cfg, getattr(ds, "depth_disparity_sigma_px", None))  # the auto (-1) of the RGB-D depth weight
    system = _continue_map(cfg, ds, sensor, map_dir, output, path, imu_inputs) if map_dir is not None else System(cfg, ds.camera, sensor=sensor, **imu_inputs)
    system.plots = plots
    log.info("running %s (%s, %d frames) as %s", path, ds.kind, stop - start_frame, sensor)
    viewer, on_frame = open_viewer(viz, system, viz_options) if viz else (None, None)
    try:
        result = run_sequence(
            system, FrameRange(ds, start_frame, stop), total=stop - start_frame, prefetch_mode=prefetch, output_dir=output, config=cfg,
            ground_truth=truth.trajectory, align="sim3" if sensor == "mono" else "se3", progress=progress, on_frame=on_frame,
            extra_stats={"sensor": sensor, "dataset": ds.kind, "path": str(Path(path).resolve()),
                         "start_frame": start_frame, **truth.stats(), **_inertial_metadata(imu_inputs),
                         **({"camera": ds.calibration_source} if getattr(ds, "calibration_source", None) else {})},
            inputs=(path,),
        )
    finally:
        if viewer is not None:
            viewer.close()
    plot = (truth.trajectory, sensor) if plots else None
    return _extra_outputs(result, output, trajectory_format, dense, progress, plot)


def _is_live(dataset: str | None, path, dense: bool, start_frame: int) -> bool:
    """Whether ``path`` is a live source (or ``dataset`` says so); DatasetError for what live input
    cannot do."""
    from vslam.datasets.live import is_live_source

    if not (dataset == "live" or (dataset is None and is_live_source(str(path)))):
        return False
    if dense:
        raise DatasetError("--dense needs depth; live input is mono")
    if start_frame:
        raise DatasetError("--start-frame does not apply to live input")
    return True


def _open_run(path, dataset, sensor, imu, map_dir, dense: bool, start_frame: int, max_frames, camera, topics):
    """:func:`open_sequence` for ``run_path``: ``(dataset, sensor, stop, System's IMU arguments)``.

    An inertial sensor (``mono-inertial`` ...) reads the base sensor's frames and the IMU: the
    dataset's (EuRoC ``imu0/``) or ``imu``, a file with EuRoC CSV columns, its calibration beside it
    (:func:`vslam.datasets.imu.dataset_imu`); :class:`vslam.system.System` then initializes a
    gravity-aligned (z up), metric world and predicts each frame's pose with the IMU."""
    base, inertial = _split_requested(sensor, imu, map_dir)
    ds, base, stop = open_sequence(path, dataset, base, start_frame, max_frames, camera=camera,
                                   options={"topics": topics} if topics else {})
    if getattr(ds, "calibration_source", None):
        log.info("camera: %s", ds.calibration_source)
    if dense and base == "mono":
        raise DatasetError("--dense needs depth: run with --sensor rgbd or stereo")
    return ds, f"{base}-inertial" if inertial else base, stop, (imu_inputs(ds, imu) if inertial else {})


def _split_requested(sensor: str | None, imu, map_dir) -> tuple[str | None, bool]:
    """``(base sensor or None, inertial)`` of the requested sensor; ``imu`` needs an inertial one."""
    from vslam.errors import ConfigError
    from vslam.inertial.sensors import INERTIAL_SENSORS, split_sensor

    base, inertial = split_sensor(sensor) if sensor is not None else (None, False)
    if imu is not None and not inertial:
        raise ConfigError(f"--imu is read by the inertial sensors only: add --sensor {' | '.join(INERTIAL_SENSORS)}")
    return base, inertial


def _inertial_metadata(imu_inputs: dict) -> dict:
    """``{"inertial": ...}`` for the stats and the saved map's metadata of an inertial run (gravity
    magnitude, IMU calibration source, ``T_imu_cam``: :func:`vslam.map.io_inertial.inertial_metadata`)."""
    if not imu_inputs:
        return {}
    from vslam.map.io_inertial import inertial_metadata

    return {"inertial": inertial_metadata(imu_inputs["imu_calibration"])}


def imu_inputs(ds, imu) -> dict:
    """``System``'s (and the localizer's) ``imu`` and ``imu_calibration`` for an inertial run
    (:func:`vslam.datasets.imu.dataset_imu`)."""
    from vslam.datasets.imu import dataset_imu

    samples, calib = dataset_imu(ds, imu)
    log.info("IMU: %d samples from %s", len(samples), samples.source or imu)
    return {"imu": samples, "imu_calibration": calib}


def _trajectory_png(result, out: Path, ground_truth, sensor: str) -> None:
    """``trajectory.png`` of the run (:func:`vslam.eval.run_plot.plot_run_trajectory`); a failure
    is a warning, the run's results are written."""
    from vslam.eval.run_plot import plot_run_trajectory

    try:
        plot_run_trajectory(result.trajectory, out / "trajectory.png", ground_truth,
                            align="sim3" if sensor == "mono" else "se3", title=f"vslam run ({sensor})",
                            mono=sensor == "mono")
    except Exception as exc:  # noqa: BLE001 - a plot never fails a finished run
        log.warning("%s: trajectory.png not written (%s: %s)", out, type(exc).__name__, exc)


def open_viewer(viz: str, system, viz_options: dict | None = None):
    """``(viewer, on_frame)`` for ``--viz``; ``(None, None)`` with a warning, said at the start,
    when no viewer can open here (:class:`~vslam.viz.rerun_viewer.ViewerUnavailable`: a headless
    machine, say), so the run goes on without one."""
    from vslam.viz.rerun_viewer import RerunViewer, ViewerUnavailable

    try:
        viewer = RerunViewer.from_spec(viz, system=system, **(viz_options or {}))
    except ViewerUnavailable as exc:
        log.warning("%s; running without a viewer", exc)
        return None, None
    return viewer, viewer.bind(system)


def _continue_map(cfg, ds, sensor: str, map_dir: str | Path, output: str | Path | None = None, path=None,
                  imu_inputs: dict | None = None):
    """A :class:`System` continuing the map saved in ``map_dir`` (same sensor, same image size). A
    SIGTERM / Ctrl-C while the map loads leaves ``output/stats.json`` with its error, as one during
    the run does; a map another command is writing is waited for, or refused naming it, and a
    stopped in-place run's map is read from ``.previous-run/`` (:func:`vslam.map.io.load_run_map`).
    An inertial sensor (``imu_inputs``: the System's IMU arguments) continues a gravity-aligned map
    (:func:`_continue_inertial`)."""
    from vslam.errors import MapFormatError
    from vslam.map.io import load_run_map
    from vslam.runner import error_stats_when_stopped
    from vslam.system import System

    where = {"map": str(Path(map_dir).resolve()), "path": str(Path(path).resolve()) if path is not None else None,
             "sensor": sensor}
    with error_stats_when_stopped(output, (path,) if path is not None else (), where):
        slam_map, database, camera, meta = load_run_map(map_dir, "the map", "continue", cfg.loop.database)
    if meta.get("sensor") not in (None, sensor):
        raise MapFormatError(f"{map_dir}: a {meta.get('sensor')!r} map cannot be continued with {sensor!r} frames")
    if camera is not None and (camera.width, camera.height) != (ds.camera.width, ds.camera.height):
        raise MapFormatError(f"{map_dir}: the map's camera is {camera.width}x{camera.height}, the sequence's "
                             f"{ds.camera.width}x{ds.camera.height}")
    log.info("continuing the map in %s (%d keyframes)", map_dir, len(slam_map.keyframes))
    if imu_inputs:
        system = _continue_inertial(cfg, ds, sensor, map_dir, slam_map, database, imu_inputs)
    else:
        system = System.from_map(cfg, ds.camera, sensor, slam_map, database)
    system.map_loaded = str(Path(map_dir).resolve())  # stats.json's map_loaded
    return system


def _continue_inertial(cfg, ds, sensor: str, map_dir, slam_map, database, imu_inputs: dict):
    """A :class:`System` with the IMU continuing the gravity-aligned ``slam_map``. The first frames are
    placed in it by global relocalization, as for a visual sensor; once placed, the session's IMU
    starts from the map's gravity, scale and biases (:mod:`vslam.imu_from_map`: no initialization of
    its own, so a clip too short for one still lands in the map, metric). Frames that cannot be
    placed (``frontend.tracking.max_frames_to_place``) start a new segment past the loaded ones
    (ORB-SLAM3's Atlas: a new map, merged later): its IMU initializes there (the gravity-aligned move
    leaves the loaded segments where they are, :func:`vslam.backend.inertial_mapping.move_map`), and
    loop closing joins it to the loaded map by a yaw + translation once it recognizes a loaded place
    (:mod:`vslam.loop.segment_merging`; the join waits for the IMU initialization)."""
    from vslam.errors import ConfigError, MapFormatError
    from vslam.imu_from_map import MapImuStart
    from vslam.system import System

    if not slam_map.gravity_aligned:
        raise MapFormatError(f"{map_dir}: the map is not gravity-aligned (its run never initialized an IMU); "
                             f"continue it with --sensor {sensor.removesuffix('-inertial')}")
    system = System(cfg, ds.camera, sensor=sensor, slam_map=slam_map, **imu_inputs)
    if system.loop_closer is None:
        raise ConfigError("continuing a map needs loop.enabled (its keyframe database finds the places)")
    system.loop_closer.adopt_keyframes(database)
    system.map_imu_start = MapImuStart(system)
    if hasattr(system.local_mapper, "first_session_kf"):
        system.local_mapper.first_session_kf = max(slam_map.keyframes) + 1
    system.tracker.start_in_map(system.frontend_config.tracking.max_frames_to_place)
    system.loaded_keyframes = len(slam_map.keyframes)
    return system


def _extra_outputs(result, output: str | Path | None, trajectory_format: str, dense: bool, progress: bool,
                   plot: tuple | None = None):
    """After a run: ``trajectory.png`` (``plot``: ``(ground truth, sensor)``), the trajectory in
    another format (``--trajectory-format``) and the TSDF mesh (``--dense``), recorded in the stats.
    A SIGTERM / Ctrl-C meanwhile rewrites ``stats.json`` with its ``error`` (these outputs may be
    missing), as a run stopped earlier leaves it."""
    from vslam.runner import write_error_stats, write_stats

    try:
        if plot is not None and output is not None and len(result.trajectory) >= 2:
            _trajectory_png(result, Path(output), *plot)
        if trajectory_format != "tum" and output is not None and len(result.trajectory):
            result.stats["trajectory_export"] = str(export_trajectory(Path(output), result.trajectory,
                                                                      trajectory_format))
        if dense and output is not None:
            from vslam.reconstruction import reconstruct_run

            result.stats["dense"] = reconstruct_run(output, progress=progress_bar(progress))
            write_stats(Path(output), result.stats)
    except KeyboardInterrupt as exc:
        if output is not None:
            write_error_stats(Path(output), exc, result.stats)
        raise
    return result


def run_live(
    source: str,
    output: str | Path | None,
    camera: str | Path | None = None,
    config: str | Path | object | None = None,
    overrides: list[str] | tuple[str, ...] = (),
    max_frames: int | None = None,
    progress: bool = False,
    viz: str | None = None,
    trajectory_format: str = "tum",
    options: dict | None = None,
    on_frame=None,
    viz_options: dict | None = None,
):
    """Run SLAM on a live camera or stream (``camera:0``, ``rtsp://...``; see :mod:`vslam.datasets.live`).

    ``camera`` (a calibration file) is required. The backend runs in ``realtime`` mode (local
    mapping and loop closing in their own threads) unless ``overrides`` set ``backend.mode``. The
    tracker always gets the newest frame; frames that arrived while it was busy are dropped and
    counted (``dropped_frames`` in the stats, ``captured_frames`` all frames grabbed). The run
    ends when the stream ends, after ``max_frames``, or on Ctrl-C (SIGINT, when called from the
    main thread: the first one ends the run normally, with the trajectory, map and stats written;
    a second one aborts). ``options`` go to :class:`~vslam.datasets.live.LiveDataset` (``fps``,
    ``clock``); ``on_frame(frame, result)`` is called after each tracked frame.
    Returns a :class:`vslam.runner.RunResult`.
    """
    import dataclasses
    import signal
    import threading

    from vslam.datasets.live import LiveDataset
    from vslam.runner import run_sequence
    from vslam.system import System

    cfg = resolve_config(config, overrides)
    if not any(str(o).split("=", 1)[0].strip() == "backend.mode" for o in overrides):
        cfg = dataclasses.replace(cfg, backend=dataclasses.replace(cfg.backend, mode="realtime"))
    ds = LiveDataset(str(source), camera=camera, **(options or {}))
    log.info("camera: %s", ds.calibration_source)
    system = System(cfg, ds.camera, sensor="mono")
    callbacks = [on_frame] if on_frame is not None else []
    viewer = None
    previous_handler, installed = None, False
    stats = {"sensor": "mono", "dataset": "live", "path": str(source), "start_frame": 0,
             "camera": ds.calibration_source}
    try:
        viewer = open_viewer(viz, system, viz_options)[0] if viz else None
        if viewer is not None:
            callbacks.insert(0, viewer.bind(system))
        if threading.current_thread() is threading.main_thread():
            def stop_on_sigint(signum, frame):  # first Ctrl-C: end the stream, keep every output
                log.warning("%s: stopping (Ctrl-C again to abort)", source)
                ds.stop()
                signal.signal(signal.SIGINT, previous_handler or signal.default_int_handler)

            previous_handler = signal.signal(signal.SIGINT, stop_on_sigint)
            installed = True
        log.info("running live %s (mono, %s)", source, cfg.backend.mode)
        result = run_sequence(
            system, ds.frames(max_frames, counts=stats), total=max_frames, prefetch_mode="none", output_dir=output,
            config=cfg, progress=progress, extra_stats=stats,
            on_frame=(lambda f, r: [cb(f, r) for cb in callbacks]) if callbacks else None,
        )
    finally:
        if installed:
            signal.signal(signal.SIGINT, previous_handler if previous_handler is not None else signal.default_int_handler)
        if viewer is not None:
            viewer.close()
        ds.close()
    if trajectory_format != "tum" and output is not None and len(result.trajectory):
        result.stats["trajectory_export"] = str(export_trajectory(Path(output), result.trajectory, trajectory_format))
    return result
