"""Run a whole sequence through a :class:`~vslam.system.System` and write the results to a folder.

Outputs (the contract of ``vslam run``):

* ``trajectory.txt``: TUM format, ``T_world_cam`` of every tracked frame with the dataset's
  timestamps. Written and flushed frame by frame, whole lines only (a failed write is cut back),
  so an interrupted or crashed run keeps what it had; rewritten at the end (atomically) with the
  final (optimized) poses.
* ``keyframes.txt``: the keyframe trajectory, TUM format.
* ``stats.json``: counts (``skipped_frames``: unreadable frames the reader skipped), ``error`` when
  the run failed or was stopped, timings (``read_ms``: mean wait of the tracker for a decoded frame;
  ``stage_ms``: the system's per-stage times), loops, and ATE/RPE when ground truth is known.
* ``config.yaml``: the fully resolved configuration.

Frames are decoded (and, by the system's ``prepare``, converted to gray and their features
detected) in a background thread a few frames ahead of tracking
(:func:`vslam.datasets.prefetch.prefetch`), so on a machine with two cores decoding and detection
overlap tracking.
"""
from __future__ import annotations

import json
import logging
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator

import numpy as np

from vslam.config import dump_config
from vslam.errors import OutputError
from vslam.trajectory import Trajectory, format_tum_line, tum_rows_from_poses, write_tum
from vslam.outputs import LineWriter, atomic_path, atomic_write_text, open_run_dir
from vslam.signals import interrupt_reason

log = logging.getLogger(__name__)


@dataclass
class RunResult:
    """What a run produced: the summary written to ``stats.json`` and the final trajectory."""

    stats: dict
    trajectory: Trajectory
    output_dir: Path | None = None


def _atomic_write_tum(path: Path, traj: Trajectory) -> None:
    with atomic_path(path) as tmp:
        write_tum(tmp, traj)


def write_stats(out_dir: Path, stats: dict) -> None:
    """(Re)write ``out_dir/stats.json`` atomically."""
    _write_json(Path(out_dir) / "stats.json", stats)


def _write_json(path: Path, data: dict) -> None:
    atomic_write_text(path, json.dumps(data, indent=2, default=_json_default))


def _json_default(obj: Any) -> Any:
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (np.floating,)):
        return float(obj)
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    raise TypeError(f"not JSON serializable: {type(obj)}")


def _rss_mb() -> float | None:
    """Resident memory of this process in MB (Linux ``/proc/self/statm``; None elsewhere)."""
    try:
        with open("/proc/self/statm") as f:
            pages = int(f.read().split()[1])
        return round(pages * os.sysconf("SC_PAGE_SIZE") / 2**20, 1)
    except (OSError, ValueError, IndexError, AttributeError):
        return None


def run_sequence(
    system: Any,
    frames: Iterable[Any],
    total: int | None = None,
    output_dir: str | Path | None = None,
    config: Any = None,
    ground_truth: Trajectory | None = None,
    align: str = "se3",
    progress: bool = True,
    on_frame: Callable[[Any, Any], None] | None = None,
    extra_stats: dict | None = None,
    prefetch_depth: int = 4,
    cv_threads: int | None = 1,
    prefetch_mode: str = "thread",
    inputs: tuple[str | Path, ...] = (),
) -> RunResult:
    """Feed ``frames`` to ``system.track`` one by one and collect (and optionally write) the results.

    Args:
        system: a :class:`vslam.system.System` (anything with ``track``, ``finish``,
            ``trajectory``, ``keyframe_trajectory`` and ``stats``).
        frames: an iterable of :class:`~vslam.datasets.frame.Frame` (streamed, never materialized).
        total: number of frames, for the progress bar.
        output_dir: where to write the outputs; None writes nothing.
        config: the resolved configuration, written as ``config.yaml``.
        ground_truth: when given, ATE/RPE are computed and added to the stats.
        align: ``se3`` or ``sim3`` (monocular) for the ATE.
        on_frame: optional callback ``(frame, track_result)``, e.g. a live viewer.
        prefetch_depth: frames decoded ahead in a background thread while the current one is
            tracked (:func:`vslam.datasets.prefetch.prefetch`; bounded, so memory stays flat);
            that thread also runs the system's ``prepare(frame)`` (or its tracker's: grayscale
            and feature detection) when it has one, on the frames it decoded while the tracker
            was busy (so the work balances between the threads). 0 decodes in the tracking thread.
        prefetch_mode: ``thread`` (above), ``process`` (``frames`` must be a
            :class:`~vslam.datasets.prefetch.FrameRange`: reading and ``prepare`` then run in a
            child process, :func:`~vslam.datasets.prefetch.prefetch_process`, free of the GIL;
            the poses are the same), ``auto`` (:func:`~vslam.datasets.prefetch.choose_prefetch`)
            or ``none`` (everything in the tracking thread).
        cv_threads: size of OpenCV's own thread pool during the run (``cv2.setNumThreads``,
            restored afterwards); None leaves it alone. 1 by default: the run already keeps two
            threads busy (tracking and prefetching), and OpenCV's pool competing with them for
            the cores cost more CPU per frame than it saved (``benchmarks/frontend_speed.py``).
        inputs: the input paths, which ``output_dir`` must not be.

    The output folder is locked for the run and a previous run's outputs in it are moved aside
    (:func:`vslam.outputs.open_run_dir`); frames the reader skipped (corrupt) are counted in
    ``skipped_frames``. A failed or stopped run still writes ``stats.json`` with an ``error``.

    Raises:
        OutputError: the output folder cannot be used or an output cannot be written (disk full).
    """
    out = Path(output_dir) if output_dir is not None else None
    run_dir = open_run_dir(out, inputs) if out is not None else None
    try:
        if out is not None and config is not None:
            with atomic_path(out / "config.yaml") as tmp:
                dump_config(config, tmp)
        traj_file = LineWriter(out / "trajectory.txt") if out is not None else None
        if traj_file is not None:
            traj_file.write("# timestamp tx ty tz qx qy qz qw  (T_world_cam)\n")
    except BaseException:
        if run_dir is not None:
            run_dir.release()
        raise
    try:
        result = _run(system, frames, total, out, ground_truth, align, progress, on_frame, extra_stats,
                      prefetch_depth, cv_threads, prefetch_mode, traj_file)
    finally:
        if run_dir is not None:
            run_dir.release()
    if run_dir is not None:
        run_dir.finish()
    return result


def _run(system, frames, total, out, ground_truth, align, progress, on_frame, extra_stats, prefetch_depth,
         cv_threads, prefetch_mode, traj_file) -> RunResult:
    """The loop of :func:`run_sequence`, writing into the prepared folder ``out`` (or nothing)."""
    from tqdm import tqdm

    from vslam.datasets.prefetch import PROCESS_HEAD_FRAMES, choose_prefetch, prefetch, prefetch_process

    n_frames = n_tracked = n_lost = n_gaps = 0
    last_index: int | None = None
    t_start = time.perf_counter()
    error: str | None = None
    bar = tqdm(total=total, desc="tracking", unit="frame", disable=not progress, file=sys.stderr,
               dynamic_ncols=True, leave=False)
    # per-frame work that needs no tracking state (detection) runs in the decoding thread too
    mode = "none" if prefetch_depth <= 0 else choose_prefetch(prefetch_mode, frames, total)
    if mode == "process":
        source = _adopting(system, prefetch_process(frames, getattr(system, "frame_preparer", lambda: None)(),
                                                    prefetch_depth, head=PROCESS_HEAD_FRAMES))
    else:
        source = prefetch(frames, prefetch_depth if mode == "thread" else 0, getattr(system, "prepare", None))
    log.debug("prefetching frames: %s", mode)
    cv_threads_before = None
    if cv_threads is not None:
        import cv2

        cv_threads_before = cv2.getNumThreads()
        cv2.setNumThreads(int(cv_threads))
    t_read = 0.0  # time the tracking thread waited for the next decoded frame
    rss: list[list] = [[0, _rss_mb()]]  # resident memory every 100 frames (flat apart from the map)
    try:
        while True:
            t0 = time.perf_counter()
            try:
                frame = next(source)
            except StopIteration:
                break
            t_read += time.perf_counter() - t0
            index = getattr(frame, "index", None)
            if isinstance(index, (int, np.integer)):
                if last_index is not None and index > last_index + 1:
                    n_gaps += int(index - last_index - 1)  # frames the reader skipped (corrupt)
                last_index = int(index)
            result = system.track(frame)
            n_frames += 1
            if result.T_world_cam is not None:
                n_tracked += 1
                if traj_file is not None:
                    row = tum_rows_from_poses(result.T_world_cam[None])[0]
                    traj_file.write(format_tum_line(frame.timestamp, row))
            elif result.state == "lost":
                n_lost += 1
            if on_frame is not None:
                on_frame(frame, result)
            bar.update(1)
            if n_frames % 10 == 0:
                bar.set_postfix(tracked=n_tracked, lost=n_lost, refresh=False)
            if n_frames % 100 == 0:
                rss.append([n_frames, _rss_mb()])
        system.finish()
    except KeyboardInterrupt as exc:
        error = interrupt_reason(exc)
        raise
    except Exception as exc:  # keep what we have, then re-raise
        error = f"{type(exc).__name__}: {exc}"
        raise
    finally:
        source.close()  # stops the decoding thread (a no-op once the frames are exhausted)
        if cv_threads_before is not None:
            import cv2

            cv2.setNumThreads(cv_threads_before)
        bar.close()
        wall = time.perf_counter() - t_start
        if traj_file is not None:
            traj_file.close()
        skipped = n_gaps
        if error is None and total is not None:
            skipped = max(skipped, int(total) - n_frames)
        stats = {
            "frames": n_frames,
            "skipped_frames": skipped,
            "tracked": n_tracked,
            "lost": n_lost,
            "wall_s": round(wall, 3),
            "fps": round(n_frames / wall, 2) if wall > 0 else 0.0,
            "read_ms": round(1000.0 * t_read / max(n_frames, 1), 3),  # mean wait for a decoded frame
            "prefetch": mode,  # where frames were decoded and features detected ahead (thread / process / none)
            "rss_mb": rss,  # [[frames done, resident MB], ...]
        }
        try:
            stats.update(system.stats())
        except Exception:  # never lose the run summary because of a stats failure
            log.exception("collecting system stats failed")
        stats.setdefault("loops", [])
        if extra_stats:
            stats.update(extra_stats)
        if error is not None:
            stats["error"] = error
        trajectory = Trajectory(np.zeros(0), np.zeros((0, 4, 4)))
        output_error = None
        if error is None:
            trajectory = system.trajectory()
            # frames posed after the fact (seen before a monocular initialization) count as tracked
            stats["tracked"] = max(int(stats["tracked"]), len(trajectory))
            if out is not None:
                output_error = _write_outputs(system, out, trajectory, stats, extra_stats)
            if ground_truth is not None and len(trajectory) >= 3:
                stats.update(_evaluate(trajectory, ground_truth, align))
        if out is not None:
            if output_error is not None:
                stats["error"] = output_error
            try:
                _write_json(out / "stats.json", stats)
            except OutputError as exc:
                if error is None and output_error is None:
                    raise
                if output_error is not None:
                    output_error += "; stats.json could not be written either"
                else:
                    log.error("%s", exc)  # the run's own error is the one to report
    if output_error is not None:
        raise OutputError(output_error)
    return RunResult(stats=stats, trajectory=trajectory, output_dir=out)


def _write_outputs(system: Any, out: Path, trajectory: Trajectory, stats: dict, extra_stats: dict | None) -> str | None:
    """Write the final trajectory, keyframes and map outputs; the first failure as one line (or None)."""
    step = out / "trajectory.txt"
    try:
        if len(trajectory):
            _atomic_write_tum(step, trajectory)
        step = out / "keyframes.txt"
        with atomic_path(step) as tmp:
            write_tum(tmp, system.keyframe_trajectory())
        if hasattr(system, "save_map_outputs"):
            step = out / "map"  # with sparse.ply and topology.*
            stats["outputs"] = system.save_map_outputs(out, metadata=extra_stats)
    except OutputError as exc:
        return str(exc)
    except OSError as exc:
        from vslam.outputs import describe_os_error

        return describe_os_error(exc, step)
    except Exception as exc:  # the trajectory and stats are safe; report it in one line, don't lose them
        log.debug("writing the map outputs failed", exc_info=True)
        return f"{out}: writing the map outputs failed ({type(exc).__name__}: {exc})"
    return None


def _adopting(system: Any, items: Iterator[tuple[Any, Any, float]]) -> Iterator[Any]:
    """Frames from :func:`~vslam.datasets.prefetch.prefetch_process`, each handing its prepared
    result to ``system.adopt_prepared`` before the tracker gets it."""
    try:
        for frame, result, seconds in items:
            if result is not None:
                system.adopt_prepared(frame, result, seconds)
            yield frame
    finally:
        items.close()


def _evaluate(traj: Trajectory, gt: Trajectory, align: str) -> dict:
    """ATE/RPE against ground truth, as in ``vslam eval`` (returns {} when they do not overlap)."""
    from vslam.errors import VslamError
    from vslam.eval import evaluate_trajectories

    try:
        res = evaluate_trajectories(traj, gt, align=align)
    except VslamError as exc:
        log.warning("evaluation against ground truth skipped: %s", exc)
        return {}
    d = res.to_dict()
    return {k: d[k] for k in ("ate_rmse", "rpe_trans_rmse", "rpe_rot_deg_rmse", "matched_poses", "scale") if k in d}
