"""Localize a sequence in a saved map (the API behind ``vslam localize``).

Example::

    from vslam.localize import localize_path
    result = localize_path("runs/kitchen", "data/kitchen", "runs/kitchen_loc", start_frame=600)
    print(result.stats["localized_ratio"], result.stats.get("ate_rmse"))

Outputs in ``output``:

* ``trajectory.txt``: TUM, ``T_world_cam`` (in the map's world frame) of every localized frame only,
  written and flushed frame by frame;
* ``stats.json``: frame counts (frames, localized = tracked + relocalized, tracked, relocalizations,
  lost), wall time, fps, per-stage mean milliseconds, and ATE/RPE against the dataset's ground
  truth when it has some (SE(3) alignment; Sim(3) for monocular maps).
"""
from __future__ import annotations

import logging
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from vslam.errors import MapFormatError

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
):
    """Localize the frames ``start_frame ..`` of the sequence at ``path`` in the map saved in ``map_dir``.

    ``config`` defaults to the mapping run's ``MAP_DIR/config.yaml`` when there is one (so features are
    detected as they were for the map); ``overrides`` set the root Config, its ``localize.`` section
    (:class:`vslam.config.LocalizerConfig`) included.
    Returns a :class:`vslam.runner.RunResult` (``stats`` and the trajectory of the localized frames).
    Raises :class:`MapFormatError` for a missing or corrupt map, :class:`DatasetError` for a bad sequence.
    """
    from tqdm import tqdm

    from vslam.api import open_sequence, resolve_config
    from vslam.trajectory import Trajectory, format_tum_line, tum_rows_from_poses
    from vslam.localizer import Localizer
    from vslam.map.io import load_map
    from vslam.runner import RunResult, _evaluate, write_stats

    map_dir = Path(map_dir)
    if config is None and (map_dir / "config.yaml").is_file():
        config = map_dir / "config.yaml"  # detect features as the mapping run did
    cfg = resolve_config(config, list(overrides))
    loc_cfg = cfg.localize

    if not map_dir.exists():
        raise MapFormatError(f"{map_dir}: no such map folder (give the --output folder of a `vslam run`)")
    slam_map, database, map_camera, metadata = load_map(map_dir)
    if not slam_map.keyframes:
        raise MapFormatError(f"{map_dir}: the map has no keyframes; nothing to localize against")

    ds, sensor, stop = open_sequence(path, dataset, sensor, start_frame, max_frames,
                                     preferred_sensor=metadata.get("sensor"), camera=camera)
    camera = ds.camera
    if map_camera is not None and (abs(map_camera.fx - camera.fx) > 1e-3 * camera.fx
                                   or map_camera.width != camera.width or map_camera.height != camera.height):
        log.warning("the sequence's camera (fx %.1f, %dx%d) differs from the map's (fx %.1f, %dx%d)",
                    camera.fx, camera.width, camera.height, map_camera.fx, map_camera.width, map_camera.height)
    localizer = Localizer(slam_map, database, camera, cfg, sensor=sensor, localize_config=loc_cfg)

    from vslam.outputs import LineWriter, open_run_dir
    from vslam.signals import interrupt_reason

    out = Path(output) if output is not None else None
    traj_file = None
    run_dir = None
    if out is not None:  # never the map's folder or the sequence; locked; a previous result moved aside
        run_dir = open_run_dir(out, inputs=(path, map_dir, map_dir / "map"))
        try:
            traj_file = LineWriter(out / "trajectory.txt")
            traj_file.write("# timestamp tx ty tz qx qy qz qw  (T_world_cam, map frame)\n")
        except BaseException:
            run_dir.release()
            raise
    stamps: list[float] = []
    poses: list[np.ndarray] = []
    t_start = time.perf_counter()
    bar = tqdm(total=stop - start_frame, desc="localizing", unit="frame", disable=not progress, file=sys.stderr,
               dynamic_ncols=True, leave=False)
    error: str | None = None
    try:
        for frame in ds.frames(start_frame, stop):
            res = localizer.localize(frame)
            if res.T_world_cam is not None:
                stamps.append(float(frame.timestamp))
                poses.append(res.T_world_cam)
                if traj_file is not None:
                    row = tum_rows_from_poses(res.T_world_cam[None])[0]
                    traj_file.write(format_tum_line(frame.timestamp, row))
            bar.update(1)
    except KeyboardInterrupt as exc:
        error = interrupt_reason(exc)
        raise
    except Exception as exc:
        error = f"{type(exc).__name__}: {exc}"
        raise
    finally:
        bar.close()
        if traj_file is not None:
            traj_file.close()
        wall = time.perf_counter() - t_start
        s = localizer.stats()
        n_frames = s["frames"]
        n_loc = len(poses)
        stats: dict[str, Any] = {
            "frames": n_frames,
            "skipped_frames": ds.skipped,
            "localized": n_loc,
            "localized_ratio": round(n_loc / n_frames, 4) if n_frames else 0.0,
            **{k: s[k] for k in ("tracked", "relocalizations", "relocalization_attempts", "track_failures", "implausible_steps", "lost")},
            "wall_s": round(wall, 3),
            "fps": round(n_frames / wall, 2) if wall > 0 else 0.0,
            "stage_ms": s["stage_ms"],
            "sensor": sensor,
            "dataset": ds.kind,
            "path": str(Path(path).resolve()),
            "map": str(map_dir.resolve()),
            "map_keyframes": len(slam_map.keyframes),
            "map_points": int(slam_map.points.n_alive),
            "start_frame": start_frame,
        }
        if error is not None:
            stats["error"] = error
        traj = Trajectory(np.asarray(stamps, float), np.stack(poses) if poses else np.zeros((0, 4, 4)))
        if error is None:
            gt = ds.ground_truth()
            if gt is not None and len(traj) >= 3:
                stats.update(_evaluate(traj, gt, "sim3" if sensor == "mono" else "se3"))
        try:
            if out is not None:
                write_stats(out, stats)
        finally:
            if run_dir is not None:
                run_dir.release()
    if run_dir is not None:
        run_dir.finish()
    return RunResult(stats=stats, trajectory=traj, output_dir=out)
