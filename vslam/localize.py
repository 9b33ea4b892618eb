"""Localize a sequence in a saved map (the API behind ``vslam localize``).

Example::

    from vslam.localize import localize_path
    result = localize_path("runs/kitchen", "data/kitchen", "runs/kitchen_loc", start_frame=600)
    print(result.stats["localized_ratio"], result.stats.get("ate_rmse"))

Outputs in ``output``:

* ``trajectory.txt``: TUM, ``T_world_cam`` (in the map's world frame) of every localized frame only,
  written and flushed frame by frame;
* ``stats.json``: frame counts (frames, localized = tracked + relocalized, tracked, relocalizations,
  lost), wall time, fps, per-stage mean milliseconds, the map's size, and ATE/RPE against the
  dataset's ground truth when it has some (SE(3) alignment; Sim(3) for monocular maps).

The run itself is :func:`vslam.runner.run_sequence` driving a :class:`vslam.localizer.Localizer`
(the loop of ``vslam run``: frames decoded ahead, poses streamed, the output folder locked, a
stopped or failed run's ``stats.json`` with its ``error``); this module opens the map and wires it.
"""
from __future__ import annotations

import dataclasses
import logging
from pathlib import Path
from typing import Any

log = logging.getLogger(__name__)


def localize_path(
    map_dir: str | Path,
    path: str | Path,
    output: str | Path | None,
    sensor: str | None = None,
    dataset: str | None = None,
    start_frame: int = 0,
    max_frames: int | None = None,
    config: str | Path | Any | None = None,
    overrides: list[str] | tuple[str, ...] = (),
    progress: bool = False,
    camera: str | Path | None = None,
    prefetch: str = "auto",
    gt: str | Path | None = None,
    imu: str | Path | None = None,
):
    """Localize the frames ``start_frame ..`` of the sequence at ``path`` in the map saved in ``map_dir``.

    ``config`` defaults to the mapping run's ``MAP_DIR/config.yaml`` when there is one (so features are
    detected as they were for the map); ``overrides`` set the root Config, ``localize.`` included.
    ``prefetch``: where frames are decoded ahead (:func:`vslam.runner.run_sequence`; the poses do not
    depend on it). ``gt``: the ground truth as for :func:`vslam.api.run_path`.
    An inertial ``sensor`` (the default for an inertial run's map) reads the base sensor's frames in
    the map's world as saved (``stats`` ``map_gravity_aligned``); in a gravity-aligned map the IMU (the
    dataset's, or ``imu``) predicts each frame and poses the frames vision cannot localize
    (:mod:`vslam.localizer_imu`; ``stats`` ``imu_used``, ``imu_only_frames``); a visual map has no
    gravity to integrate in: visual localization, with a warning.
    Returns a :class:`vslam.runner.RunResult` (``stats`` and the trajectory of the localized frames).
    Raises :class:`MapFormatError` for a missing or corrupt map, :class:`DatasetError` for a bad sequence.
    """
    from vslam.api import open_sequence, resolve_config
    from vslam.datasets.ground_truth import resolve_ground_truth
    from vslam.datasets.prefetch import FrameRange
    from vslam.localizer import Localizer
    from vslam.runner import error_stats_when_stopped, run_sequence

    from vslam.outputs import last_complete_run

    map_dir = Path(map_dir)
    mapping_run = last_complete_run(map_dir)[0]  # .previous-run/ after a stopped in-place run (its map is read there)
    if config is None and (mapping_run / "config.yaml").is_file():
        config = mapping_run / "config.yaml"  # detect features as the mapping run did
    inputs = (path, map_dir, map_dir / "map")
    # a SIGTERM / Ctrl-C while the map loads leaves stats.json with its error, as one during the run does
    where = {"map": str(map_dir.resolve()), "path": str(Path(path).resolve())}
    with error_stats_when_stopped(output, inputs, where):
        cfg = resolve_config(config, list(overrides))
        loc_cfg = cfg.localize
        slam_map, database, map_camera, metadata = open_map(map_dir)
        inertial = _inertial_request(sensor, metadata.get("sensor"), imu)
        ds, sensor, stop = open_sequence(path, dataset, sensor and sensor.removesuffix("-inertial"), start_frame,
                                         max_frames, preferred_sensor=metadata.get("sensor"), camera=camera)
        _check_camera(map_camera, ds.camera)
        truth = resolve_ground_truth(ds, gt, (start_frame, stop))
        # features.subpixel=auto as the mapping run resolved it (its sensor), so the keypoints match the map's
        cfg = dataclasses.replace(cfg, features=cfg.features.for_sensor(metadata.get("sensor") or sensor))
        imu_state = _imu_state(ds, imu, slam_map, cfg) if inertial else None
        localizer = Localizer(slam_map, database, ds.camera, cfg, sensor=sensor, localize_config=loc_cfg,
                              imu=imu_state)
    extra_stats = {
        "sensor": sensor,
        "dataset": ds.kind,
        "path": str(Path(path).resolve()),
        "map": str(map_dir.resolve()),
        "map_keyframes": len(slam_map.keyframes),
        "map_points": int(slam_map.points.n_alive),  # the map is never modified
        "start_frame": start_frame,
        **truth.stats(),
    }
    if inertial or slam_map.gravity_aligned:
        extra_stats.update({"sensor": f"{sensor}-inertial" if inertial else sensor,
                            "map_gravity_aligned": bool(slam_map.gravity_aligned), "imu_used": imu_state is not None})
    # never into the map's folder or the sequence; locked; a previous result moved aside
    return run_sequence(
        localizer, FrameRange(ds, start_frame, stop), total=stop - start_frame, output_dir=output,
        ground_truth=truth.trajectory, progress=progress,
        align="sim3" if sensor == "mono" and not slam_map.gravity_aligned else "se3",  # a VI map is metric
        extra_stats=extra_stats, prefetch_mode=prefetch, inputs=inputs,
    )


def localize_counts(stats: dict) -> dict:
    """One consistent set of counts of a localization run: ``frames``, ``localized`` (= ``tracked``
    + ``relocalized``), ``tracked`` (from the previous frame's pose), ``relocalized`` (globally, in
    the map), ``imu_only`` (posed by the IMU alone, an inertial sensor) and ``lost`` (= ``frames`` -
    ``localized`` - ``imu_only``: no pose), from its ``stats``."""
    frames, tracked, reloc, imu = (int(stats.get(k) or 0)
                                   for k in ("frames", "tracked", "relocalizations", "imu_only_frames"))
    return {"frames": frames, "localized": tracked + reloc, "tracked": tracked, "relocalized": reloc,
            "imu_only": imu, "lost": frames - tracked - reloc - imu}


def counts_line(stats: dict) -> str:
    """``368/400 frames localized (92.0 %: 340 tracked + 28 relocalized), 32 lost`` (and ``, 5
    posed by the IMU alone`` when there were such frames)."""
    c = localize_counts(stats)
    pct = 100.0 * c["localized"] / c["frames"] if c["frames"] else 0.0
    imu = f", {c['imu_only']} posed by the IMU alone" if c["imu_only"] else ""
    return (f"{c['localized']}/{c['frames']} frames localized ({pct:.1f} %: {c['tracked']} tracked + "
            f"{c['relocalized']} relocalized){imu}, {c['lost']} lost")


def _imu_state(ds: Any, imu: str | Path | None, slam_map: Any, cfg: Any):
    """The localizer's IMU (:class:`vslam.localizer_imu.LocalizerImu`) for an inertial sensor: the
    sequence's samples and calibration, the map's biases; None (with a warning) for a map that is
    not gravity-aligned."""
    from vslam.api import imu_inputs
    from vslam.localizer_imu import LocalizerImu
    from vslam.map.io_inertial import map_bias

    if not slam_map.gravity_aligned:
        log.warning("the map is not gravity-aligned (a visual run's): the IMU is not used, frames are "
                    "localized visually")
        return None
    inputs = imu_inputs(ds, imu)
    keyframes = [slam_map.keyframes[k] for k in sorted(slam_map.keyframes)]
    return LocalizerImu(inputs["imu"], inputs["imu_calibration"], map_bias(keyframes),
                        cfg.frontend.tracking.imu_only_max_s)


def _inertial_request(sensor: str | None, map_sensor: str | None, imu: Any = None) -> bool:
    """Whether the localization is of an inertial sensor: the one asked for, else the map's;
    ConfigError for an ``imu`` file given to a visual one."""
    from vslam.errors import ConfigError
    from vslam.inertial.sensors import split_sensor

    inertial = split_sensor(sensor)[1] if sensor is not None else bool(map_sensor and map_sensor.endswith("-inertial"))
    if imu is not None and not inertial:
        raise ConfigError("--imu is read by the inertial sensors only: add --sensor mono-inertial | "
                          "stereo-inertial | rgbd-inertial (or localize in an inertial run's map)")
    return inertial


def open_map(map_dir: Path) -> tuple[Any, Any, Any, dict]:
    """``(map, database, camera, metadata)`` of the map saved in ``map_dir``; MapFormatError when
    there is none or it has no keyframes."""
    from vslam.map.io import load_run_map

    return load_run_map(map_dir, "the map", "localize against")


def _check_camera(map_camera: Any, camera: Any) -> None:
    """Warn when the sequence's camera is not the map's (features will not match as well)."""
    if map_camera is not None and (abs(map_camera.fx - camera.fx) > 1e-3 * camera.fx
                                   or map_camera.width != camera.width or map_camera.height != camera.height):
        log.warning("the sequence's camera (fx %.1f, %dx%d) differs from the map's (fx %.1f, %dx%d)",
                    camera.fx, camera.width, camera.height, map_camera.fx, map_camera.width, map_camera.height)
