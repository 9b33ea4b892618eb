"""What a run report shows, loaded from a run folder: statistics, the estimated and ground-truth
trajectories (from the folder, else the run's dataset) and their evaluation, the sparse map, and the
loop closures placed on the trajectory."""
from __future__ import annotations

import json
import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from vslam.errors import VslamError
from vslam.textfile import open_text

log = logging.getLogger(__name__)

MAX_MAP_POINTS = 100_000


@dataclass
class RunData:
    """Everything a run report shows, loaded from a run folder."""

    folder: Path
    stats: dict
    est: Any = None  # Trajectory | None
    gt: Any = None
    gt_source: str = ""
    evaluation: Any = None  # vslam.eval.EvalResult | None
    T_gt_est: np.ndarray | None = None
    notes: list[str] = field(default_factory=list)
    frame_times: np.ndarray | None = None  # timestamp of every dataset frame index
    points: tuple[np.ndarray, np.ndarray | None] | None = None


def _open_dataset_of(stats: dict):
    from vslam.datasets import KINDS, open_dataset

    path = stats.get("path")
    if not path or not Path(path).exists():
        raise VslamError(f"the sequence {path!r} named in stats.json is not available here")
    kind = stats.get("dataset") if stats.get("dataset") in KINDS else None
    return open_dataset(path, kind=kind, sensor=stats.get("sensor"))


#: the type each known ``stats.json`` field must have (a crafted file fails with one line)
_STATS_TYPES: dict[str, tuple[type, ...]] = {
    "frames": (int,), "tracked": (int,), "lost": (int,), "skipped_frames": (int,), "start_frame": (int,),
    "loops": (list,), "stage_ms": (dict,), "path": (str,), "sensor": (str,), "dataset": (str,),
    "error": (str,), "fps": (int, float), "wall_s": (int, float), "ate_rmse": (int, float),
    "gt_file": (str,), "gt_frame": (str,), "localized": (int,), "relocalizations": (int,),
}


def _check_stats(path: Path, stats: Any) -> None:
    """Raise :class:`VslamError` naming the field when ``stats.json`` is not what ``vslam run`` writes."""
    if not isinstance(stats, dict):
        raise VslamError(f"{path}: expected a JSON object as written by `vslam run`")
    for key, types in _STATS_TYPES.items():
        v = stats.get(key)
        if v is not None and (not isinstance(v, types) or isinstance(v, bool)):
            raise VslamError(f"{path}: field {key!r} is {type(v).__name__} {v!r:.40}, expected "
                             f"{' or '.join(t.__name__ for t in types)}; fix or regenerate the file")
    for i, loop in enumerate(stats.get("loops") or []):
        if not isinstance(loop, (list, dict)):
            raise VslamError(f"{path}: loops[{i}] is {loop!r:.40}, expected a list [query frame, match frame, ...]")
    for k, v in (stats.get("stage_ms") or {}).items():
        if not isinstance(v, (int, float)) or isinstance(v, bool):
            raise VslamError(f"{path}: stage_ms[{k!r}] is {v!r:.40}, expected a number of milliseconds")


def load_run(folder: str | Path, gt: str | Path | None = None) -> RunData:
    """Load a run folder's stats, trajectory, ground truth (aligned and evaluated) and sparse map.

    ``gt`` chooses the ground truth (``vslam report --gt``): a trajectory file, ``"none"``, or None:
    ``groundtruth.txt`` in the folder, else the one the run used (``stats.json`` ``gt_file``), else
    the dataset's at ``stats.json``'s ``path``."""
    from vslam.eval import evaluate_trajectories, read_trajectory

    folder = Path(folder)
    if not (folder / "stats.json").is_file():
        raise VslamError(f"{folder}: no stats.json; pass a `vslam run` output folder or a `vslam bench` folder")
    try:
        stats = json.loads(open_text(folder / "stats.json", VslamError).read())
    except ValueError as exc:
        raise VslamError(f"{folder / 'stats.json'}: not valid JSON ({exc})") from None
    _check_stats(folder / "stats.json", stats)
    run = RunData(folder=folder, stats=stats)
    traj_path = folder / "trajectory.txt"
    if traj_path.is_file():
        try:
            run.est = read_trajectory(traj_path, "tum", duplicates="keep_last")
        except VslamError as exc:
            run.notes.append(f"trajectory not readable: {exc}")
    else:
        run.notes.append("no trajectory.txt in the run folder")
    ds = None
    try:
        ds = _open_dataset_of(stats)
        run.frame_times = np.asarray(ds.timestamps, dtype=float)
    except Exception as exc:  # noqa: BLE001 - the report works without the dataset
        log.info("dataset of %s not opened: %s", folder, exc)
    _load_ground_truth(run, ds, gt)
    if run.est is not None and run.gt is not None and len(run.est) >= 3:
        mode = "sim3" if stats.get("sensor") == "mono" else "se3"
        try:
            run.evaluation = evaluate_trajectories(run.est, run.gt, align=mode)
            run.T_gt_est = run.evaluation.alignment
        except VslamError as exc:
            run.notes.append(f"evaluation against ground truth failed: {exc}")
    ply = folder / "sparse.ply"
    if ply.is_file():
        from vslam.report.ply import read_ply_points

        try:
            run.points = read_ply_points(ply, MAX_MAP_POINTS)
        except VslamError as exc:
            run.notes.append(f"sparse.ply not readable: {exc}")
    return run


def _load_ground_truth(run: RunData, ds: Any, gt: str | Path | None) -> None:
    """Set ``run.gt`` and ``run.gt_source`` (see :func:`load_run`); problems become notes."""
    from vslam.eval import read_trajectory

    stats = run.stats
    if isinstance(gt, str) and gt.strip().lower() == "none":
        run.notes.append("no ground truth (--gt none)")
        return
    files = [Path(gt)] if gt is not None else [run.folder / "groundtruth.txt"]
    if gt is None and stats.get("gt_frame") == "as given" and isinstance(stats.get("gt_file"), str):
        files.append(Path(stats["gt_file"]))  # the run was given this file with --gt
    for gt_file in files:
        if gt is not None and not gt_file.is_file():
            raise VslamError(f"--gt {gt_file}: no such file; name a TUM, KITTI or EuRoC trajectory, or --gt none")
        if gt_file.is_file():
            try:
                run.gt = read_trajectory(gt_file, duplicates="keep_last")
                run.gt_source = str(gt_file.name if gt_file.parent == run.folder else gt_file)
                return
            except VslamError as exc:
                run.notes.append(f"{gt_file.name} not readable: {exc}")
    if gt is None and "gt_file" in stats and stats.get("gt_file") is None:
        run.notes.append("no ground truth: the run had none" + (f" ({stats['gt_problem']})" if stats.get("gt_problem")
                                                               else "") + "; choose one with --gt FILE")
        return
    if ds is not None and gt is None:
        try:
            run.gt = ds.ground_truth()
            run.gt_source = (stats.get("gt_file") or f"dataset {stats.get('path')}") if run.gt is not None else ""
        except Exception as exc:  # noqa: BLE001
            run.notes.append(f"ground truth of the dataset not readable: {exc}")
    if run.gt is None:
        run.notes.append("no ground truth (neither groundtruth.txt nor a readable dataset at stats.json's path)")


def lost_gaps(run: RunData, timestamps: np.ndarray) -> np.ndarray:
    """``(N - 1,)`` bool: True where frames without a pose (lost) lie between the poses at
    ``timestamps[i]`` and ``timestamps[i + 1]``: dataset frames between them when the dataset's
    frame times are known, else a step over 1.5 times the median step."""
    t = np.asarray(timestamps, dtype=float)
    if len(t) < 2:
        return np.zeros(max(len(t) - 1, 0), dtype=bool)
    if run.frame_times is not None and len(run.frame_times):
        ft = np.sort(np.asarray(run.frame_times, dtype=float))
        tol = 0.25 * float(np.median(np.diff(ft))) if len(ft) > 1 else 1e-3
        between = np.searchsorted(ft, t[1:] - tol) - np.searchsorted(ft, t[:-1] + tol, side="right")
        return between > 0
    dt = np.diff(t)
    return dt > 1.5 * float(np.median(dt))


def with_breaks(xy: np.ndarray, gaps: np.ndarray) -> np.ndarray:
    """``xy`` ``(N, D)`` with a NaN row after each row ``i`` where ``gaps[i]``: a plotted line
    stops there instead of joining the poses on either side of a lost stretch."""
    xy = np.asarray(xy, dtype=float)
    if not np.any(gaps):
        return xy
    return np.insert(xy, np.flatnonzero(gaps) + 1, np.nan, axis=0)


def aligned_positions(run: RunData) -> np.ndarray:
    """Every estimated position, in the ground-truth frame when an alignment exists."""
    T = run.est.T_world_cam
    if run.evaluation is not None:
        T = run.evaluation.alignment.apply(T)
    return T[:, :3, 3]


def loop_positions(run: RunData, positions: np.ndarray) -> list[tuple[np.ndarray, np.ndarray, list]]:
    """``(query_xyz, match_xyz, loop)`` for every loop of ``stats.json`` whose two frames have a pose.

    Frame indices become timestamps through the dataset (or, without it, the trajectory rows when
    every frame was tracked) and then the nearest trajectory pose within half a frame.
    """
    loops = run.stats.get("loops") or []
    if not loops or run.est is None or len(run.est) == 0:
        return []
    ts = run.est.timestamps
    if run.frame_times is not None:
        times = run.frame_times
        offset = 0
    elif len(ts) == run.stats.get("frames"):
        times, offset = ts, int(run.stats.get("start_frame", 0) or 0)
    else:
        return []
    dt = float(np.median(np.diff(ts))) if len(ts) > 1 else 1.0
    out = []
    for loop in loops:
        try:
            q, m = int(loop[0]) - offset, int(loop[1]) - offset
        except (TypeError, ValueError, IndexError):
            continue
        if not (0 <= q < len(times) and 0 <= m < len(times)):
            continue
        idx = []
        for t in (times[q], times[m]):
            j = int(np.clip(np.searchsorted(ts, t), 1, len(ts) - 1)) if len(ts) > 1 else 0
            j = j - 1 if len(ts) > 1 and abs(ts[j - 1] - t) <= abs(ts[j] - t) else j
            idx.append(j if abs(ts[j] - t) <= 0.5 * dt + 1e-6 else None)
        if None not in idx:
            out.append((positions[idx[0]], positions[idx[1]], list(loop)))
    return out
