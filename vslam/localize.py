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
):
    """Localize the frames ``start_frame ..`` of the sequence at ``path`` in the map saved in ``map_dir``.

    ``config`` defaults to the mapping run's ``MAP_DIR/config.yaml`` when there is one (so features are
    detected as they were for the map); ``overrides`` set the root Config, its ``localize.`` section
    (:class:`vslam.config.LocalizerConfig`) included. ``prefetch`` is
    where frames are decoded ahead (:func:`vslam.runner.run_sequence`; the poses do not depend on it).
    ``gt`` chooses the ground truth as for :func:`vslam.api.run_path` (None: the dataset's own,
    ``"none"``, or a trajectory file).
    ``sensor`` may be an inertial one (``stereo-inertial`` ...; the default for a map an inertial run
    made): its frames are read as the base sensor's and localized in the fixed map, whose world stays
    as saved (gravity-aligned, z up, metric for a visual-inertial map: ``stats`` ``map_gravity_aligned``).
    The localizer tracks visually; the IMU samples are not read (``stats`` ``imu_used`` false).
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
        inertial = _inertial_request(sensor, metadata.get("sensor"))
        ds, sensor, stop = open_sequence(path, dataset, sensor and sensor.removesuffix("-inertial"), start_frame,
                                         max_frames, preferred_sensor=metadata.get("sensor"), camera=camera)
        _check_camera(map_camera, ds.camera)
        truth = resolve_ground_truth(ds, gt, (start_frame, stop))
        # features.subpixel=auto as the mapping run resolved it (its sensor), so the keypoints match the map's
        cfg = dataclasses.replace(cfg, features=cfg.features.for_sensor(metadata.get("sensor") or sensor))
        localizer = Localizer(slam_map, database, ds.camera, cfg, sensor=sensor, localize_config=loc_cfg)
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
                            "map_gravity_aligned": bool(slam_map.gravity_aligned), "imu_used": False})
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
    the map) and ``lost`` (= ``frames`` - ``localized``), from its ``stats``."""
    frames, tracked, reloc = (int(stats.get(k) or 0) for k in ("frames", "tracked", "relocalizations"))
    return {"frames": frames, "localized": tracked + reloc, "tracked": tracked, "relocalized": reloc,
            "lost": frames - tracked - reloc}


def counts_line(stats: dict) -> str:
    """``368/400 frames localized (92.0 %: 340 tracked + 28 relocalized), 32 lost``."""
    c = localize_counts(stats)
    pct = 100.0 * c["localized"] / c["frames"] if c["frames"] else 0.0
    return (f"{c['localized']}/{c['frames']} frames localized ({pct:.1f} %: {c['tracked']} tracked + "
            f"{c['relocalized']} relocalized), {c['lost']} lost")


def _inertial_request(sensor: str | None, map_sensor: str | None) -> bool:
    """Whether the localization is of an inertial sensor: the one asked for, else the map's."""
    from vslam.inertial.sensors import split_sensor

    if sensor is not None:
        return split_sensor(sensor)[1]
    return map_sensor is not None and map_sensor.endswith("-inertial")


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
