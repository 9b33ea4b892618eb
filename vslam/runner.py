"""The one run loop: a whole sequence through a frame tracker (:class:`vslam.stream.FrameTracker`:
the SLAM :class:`~vslam.system.System` or the :class:`~vslam.localizer.Localizer`), results to a folder.

Outputs (the contract of ``vslam run``):

* ``trajectory.txt``: TUM format, ``T_world_cam`` of every tracked frame with the dataset's
  timestamps. Written and flushed frame by frame, whole lines only (a failed write is cut back),
  so an interrupted or crashed run keeps what it had; rewritten at the end (atomically) with the
  final (optimized) poses.
* ``keyframes.txt``: the keyframe trajectory, TUM format (trackers with keyframes).
* ``stats.json``: counts (``skipped_frames``: unreadable frames the reader skipped), ``error`` when
  the run failed or was stopped, timings (``read_ms``: mean wait of the tracker for a decoded frame;
  ``stage_ms``: the tracker's per-stage times), the tracker's own stats (loops ...), and ATE/RPE
  when ground truth is known.
* ``config.yaml``: the fully resolved configuration (when given);
* the map outputs (``map/``, ``sparse.ply``, ``topology.*``) of a tracker that builds a map.

Frames are decoded (and, by the tracker's ``prepare``, converted to gray and their features
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
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator

import numpy as np

from vslam.config import dump_config
from vslam.errors import OutputError
from vslam.trajectory import Trajectory, format_tum_line, tum_rows_from_poses, write_tum
from vslam.outputs import LineWriter, atomic_path, atomic_write_text, open_run_dir
from vslam.signals import interrupt_reason
from vslam.stream import FrameTracker

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


def write_error_stats(out_dir: Path, exc: BaseException, stats: dict) -> None:
    """``out_dir/stats.json`` with ``stats`` and the ``error`` of a command that was stopped (SIGTERM,
    Ctrl-C: ``terminated (SIGTERM)``, ``interrupted``) or failed, as a stopped run's; a failure to
    write it is logged (the command's own error is the one to report)."""
    error = interrupt_reason(exc) if isinstance(exc, KeyboardInterrupt) else f"{type(exc).__name__}: {exc}"
    try:
        write_stats(out_dir, {**stats, "error": error})
    except Exception as write_exc:  # noqa: BLE001 - never mask the command's own error
        log.error("%s", write_exc)


@contextmanager
def error_stats_when_stopped(out_dir: str | Path | None, inputs: tuple[str | Path, ...], stats: dict) -> Iterator[None]:
    """Around what a command does before its run folder is open (reading a map, building the
    configuration): a SIGTERM or Ctrl-C there still leaves ``out_dir/stats.json`` with its ``error``;
    the folder is opened then (locked, a previous run moved aside, as :func:`open_run_dir`)."""
    try:
        yield
    except KeyboardInterrupt as exc:
        if out_dir is not None:
            try:
                run_dir = open_run_dir(Path(out_dir), inputs)
            except OutputError as open_exc:
                log.error("%s", open_exc)
            else:
                write_error_stats(Path(out_dir), exc, stats)
                run_dir.release()
        raise


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
    system: FrameTracker,
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
        system: a frame tracker (:class:`vslam.stream.FrameTracker`): the SLAM
            :class:`~vslam.system.System` or the :class:`~vslam.localizer.Localizer`.
        frames: an iterable of :class:`~vslam.datasets.frame.Frame` (streamed, never materialized).
        total: number of frames, for the progress bar.
        output_dir: where to write the outputs; None writes nothing.
        config: the resolved configuration, written as ``config.yaml``.
        ground_truth: when given, ATE/RPE are computed and added to the stats.
        align: ``se3`` or ``sim3`` (monocular) for the ATE.
        on_frame: optional callback ``(frame, track_result)``, e.g. a live viewer.
        extra_stats: added to the stats (after the tracker's own) and passed to the map outputs.
        prefetch_depth: frames decoded ahead in a background thread while the current one is
            tracked (:func:`vslam.datasets.prefetch.prefetch`; bounded, so memory stays flat);
            that thread also runs the tracker's ``prepare(frame)`` when it has one (grayscale and
            feature detection), on the frames it decoded while the tracker had enough queued to
            stay busy (:data:`~vslam.datasets.prefetch.BALANCE_LEAD` frames; so the work balances
            between the threads). 0 decodes in the tracking thread.
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
    spec = _RunSpec(total, ground_truth, align, progress, on_frame, extra_stats, prefetch_depth, cv_threads,
                    prefetch_mode)
    out = Path(output_dir) if output_dir is not None else None
    run_dir = open_run_dir(out, inputs) if out is not None else None
    try:
        traj_file = _start_outputs(out, config)
    except BaseException:
        if run_dir is not None:
            run_dir.release()
        raise
    try:
        result = _run(system, frames, spec, out, traj_file)
    finally:
        if run_dir is not None:
            run_dir.release()
    if run_dir is not None:
        run_dir.finish()
    return result


@dataclass(frozen=True)
class _RunSpec:
    """The options of one :func:`run_sequence` call that the loop and its summary need."""

    total: int | None
    ground_truth: Trajectory | None
    align: str
    progress: bool
    on_frame: Callable[[Any, Any], None] | None
    extra_stats: dict | None
    prefetch_depth: int
    cv_threads: int | None
    prefetch_mode: str


@dataclass
class _Counts:
    """The run loop's own counts (the tracker's ``stats()`` override those of the same name)."""

    frames: int = 0
    tracked: int = 0  # frames with a pose
    lost: int = 0  # frames in state "lost"
    gaps: int = 0  # frames the reader skipped (corrupt), from gaps in the frame indices
    read_s: float = 0.0  # time the tracking thread waited for the next decoded frame
    rss: list[list] = field(default_factory=lambda: [[0, _rss_mb()]])  # resident MB every 100 frames
    last_index: int | None = None

    def see(self, frame: Any) -> None:
        """A frame arrived (before it is tracked): count the frames the reader skipped before it."""
        index = getattr(frame, "index", None)
        if isinstance(index, (int, np.integer)):
            if self.last_index is not None and index > self.last_index + 1:
                self.gaps += int(index - self.last_index - 1)
            self.last_index = int(index)

    def count(self, result: Any) -> None:
        """A frame was tracked with ``result``."""
        self.frames += 1
        if result.T_world_cam is not None:
            self.tracked += 1
        elif result.state == "lost":
            self.lost += 1
        if self.frames % 100 == 0:
            self.rss.append([self.frames, _rss_mb()])

    def summary(self, wall: float, mode: str, complete: bool, total: int | None) -> dict:
        """The first keys of ``stats.json``; ``complete``: the run was not cut short."""
        skipped = self.gaps
        if complete and total is not None:
            skipped = max(skipped, int(total) - self.frames)
        return {
            "frames": self.frames,
            "skipped_frames": skipped,
            "tracked": self.tracked,
            "lost": self.lost,
            "wall_s": round(wall, 3),
            "fps": round(self.frames / wall, 2) if wall > 0 else 0.0,
            "read_ms": round(1000.0 * self.read_s / max(self.frames, 1), 3),  # mean wait for a decoded frame
            "prefetch": mode,  # where frames were decoded and features detected ahead (thread / process / none)
            "rss_mb": self.rss,  # [[frames done, resident MB], ...]
        }


def _start_outputs(out: Path | None, config: Any) -> LineWriter | None:
    """Write ``config.yaml`` and open the streamed ``trajectory.txt`` (None without an output folder)."""
    if out is None:
        return None
    if config is not None:
        with atomic_path(out / "config.yaml") as tmp:
            dump_config(config, tmp)
    traj_file = LineWriter(out / "trajectory.txt")
    traj_file.write("# timestamp tx ty tz qx qy qz qw  (T_world_cam)\n")
    return traj_file


def _run(tracker: FrameTracker, frames: Iterable[Any], spec: _RunSpec, out: Path | None,
         traj_file: LineWriter | None) -> RunResult:
    """The loop of :func:`run_sequence`, writing into the prepared folder ``out`` (or nothing)."""
    counts = _Counts()
    t_start = time.perf_counter()
    error: str | None = None
    source, mode = _frame_source(tracker, frames, spec)
    log.debug("prefetching frames: %s", mode)
    try:
        with _opencv_threads(spec.cv_threads):
            _drive(tracker, source, counts, traj_file, spec)
            tracker.finish()
    except KeyboardInterrupt as exc:
        error = interrupt_reason(exc)
        raise
    except Exception as exc:  # keep what we have, then re-raise
        error = f"{type(exc).__name__}: {exc}"
        raise
    finally:
        stopped = None
        try:
            source.close()  # stops the decoding thread (a no-op once the frames are exhausted)
        except KeyboardInterrupt as exc:  # stopped right after the last frame: still concluded below
            stopped, error = exc, error or interrupt_reason(exc)
        wall = time.perf_counter() - t_start
        if traj_file is not None:
            traj_file.close()
        stats, trajectory, output_error, stopped_writing = _conclude(
            tracker, counts.summary(wall, mode, error is None, spec.total), error, spec, out)
        if stopped or stopped_writing:
            raise stopped or stopped_writing
    if output_error is not None:
        raise OutputError(output_error)
    return RunResult(stats=stats, trajectory=trajectory, output_dir=out)


def _frame_source(tracker: Any, frames: Iterable[Any], spec: _RunSpec) -> tuple[Iterator[Any], str]:
    """The frames, decoded (and prepared by the tracker's hooks) ahead in a thread or a process, or
    not; and that mode (``thread``, ``process`` or ``none``)."""
    from vslam.datasets.prefetch import PROCESS_HEAD_FRAMES, choose_prefetch, prefetch, prefetch_process

    depth = spec.prefetch_depth
    # per-frame work that needs no tracking state (detection) runs in the decoding thread too
    mode = "none" if depth <= 0 else choose_prefetch(spec.prefetch_mode, frames, spec.total)
    if mode == "process":
        preparer = getattr(tracker, "frame_preparer", lambda: None)()
        return _adopting(tracker, prefetch_process(frames, preparer, depth, head=PROCESS_HEAD_FRAMES)), mode
    return prefetch(frames, depth if mode == "thread" else 0, getattr(tracker, "prepare", None)), mode


@contextmanager
def _opencv_threads(n: int | None) -> Iterator[None]:
    """OpenCV's thread pool at ``n`` threads inside the block (None: left alone)."""
    if n is None:
        yield
        return
    import cv2

    before = cv2.getNumThreads()
    cv2.setNumThreads(int(n))
    try:
        yield
    finally:
        cv2.setNumThreads(before)


def _drive(tracker: FrameTracker, source: Iterator[Any], counts: _Counts, traj_file: LineWriter | None,
           spec: _RunSpec) -> None:
    """Track every frame of ``source``, streaming each pose to ``traj_file`` as it comes."""
    from tqdm import tqdm

    with tqdm(total=spec.total, desc="tracking", unit="frame", disable=not spec.progress, file=sys.stderr,
              dynamic_ncols=True, leave=False) as bar:
        while True:
            t0 = time.perf_counter()
            try:
                frame = next(source)
            except StopIteration:
                break
            counts.read_s += time.perf_counter() - t0
            counts.see(frame)
            result = tracker.track(frame)
            counts.count(result)
            if result.T_world_cam is not None and traj_file is not None:
                row = tum_rows_from_poses(result.T_world_cam[None])[0]
                traj_file.write(format_tum_line(frame.timestamp, row))
            if spec.on_frame is not None:
                spec.on_frame(frame, result)
            bar.update(1)
            if counts.frames % 10 == 0:
                bar.set_postfix(tracked=counts.tracked, lost=counts.lost, refresh=False)


def _conclude(tracker: FrameTracker, stats: dict, error: str | None, spec: _RunSpec,
              out: Path | None) -> tuple[dict, Trajectory, str | None, KeyboardInterrupt | None]:
    """Complete the run's ``stats`` (the tracker's, the extra ones, ATE/RPE), write the final
    outputs and ``stats.json``. Returns the stats, the final trajectory, the first output failure
    as one line (or None), and the SIGTERM / Ctrl-C that stopped the writing (or None: then
    ``stats.json`` has its ``error``, so a stopped run never leaves outputs without a stats.json)."""
    trajectory = Trajectory(np.zeros(0), np.zeros((0, 4, 4)))
    output_error, stopped = None, None
    try:
        if error is None:
            trajectory = tracker.trajectory()
            # frames posed after the fact (seen before a monocular initialization) count as tracked
            stats["tracked"] = max(int(stats["tracked"]), len(trajectory))
        _tracker_stats(tracker, stats, spec.extra_stats)
        if error is None:
            if out is not None:
                output_error = _write_outputs(tracker, out, trajectory, stats, spec.extra_stats, spec.progress)
            if spec.ground_truth is not None and len(trajectory) >= 3:
                stats.update(trajectory_errors(trajectory, spec.ground_truth, spec.align))
    except KeyboardInterrupt as exc:  # stopped while the outputs were written: stats.json says so
        stopped, error = exc, interrupt_reason(exc)
    if error is not None:
        stats["error"] = error
    if out is not None:
        with _signals_deferred():  # stats.json is never cut short by a signal
            output_error = _write_final_stats(out, stats, error, output_error)
    return stats, trajectory, output_error, stopped


def _tracker_stats(tracker: FrameTracker, stats: dict, extra_stats: dict | None) -> None:
    """Add the tracker's own stats and the extra ones to ``stats``."""
    try:
        stats.update(tracker.stats())
    except Exception:  # never lose the run summary because of a stats failure
        log.exception("collecting the tracker's stats failed")
    stats.setdefault("loops", [])
    if extra_stats:
        stats.update(extra_stats)


@contextmanager
def _signals_deferred() -> Iterator[None]:
    """SIGINT / SIGTERM / SIGHUP arriving inside the block take effect (their Python handler runs)
    when it ends; only in the main thread and for Python handlers (others are left alone)."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list[tuple[int, Any]] = []
    saved: dict = {}
    for name in ("SIGINT", "SIGTERM", "SIGHUP"):
        sig = getattr(signal, name, None)
        if sig is not None and callable(signal.getsignal(sig)):
            saved[sig] = signal.signal(sig, lambda signum, frame: caught.append((signum, frame)))
    try:
        yield
    finally:
        for sig, handler in saved.items():
            signal.signal(sig, handler)
        if caught:
            saved[caught[0][0]](*caught[0])


def _write_final_stats(out: Path, stats: dict, error: str | None, output_error: str | None) -> str | None:
    """Write ``stats.json`` (with the output failure as its ``error``); returns ``output_error``,
    extended when stats.json failed too. Raises OutputError when that was the only failure."""
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
    return output_error


def _write_outputs(tracker: Any, out: Path, trajectory: Trajectory, stats: dict,
                   extra_stats: dict | None, progress: bool = False) -> str | None:
    """Write the final trajectory, the keyframes and the map outputs (those the tracker has);
    the first failure as one line (or None)."""
    step = out / "trajectory.txt"
    try:
        if len(trajectory):
            _atomic_write_tum(step, trajectory)
        if hasattr(tracker, "keyframe_trajectory"):
            step = out / "keyframes.txt"
            with atomic_path(step) as tmp:
                write_tum(tmp, tracker.keyframe_trajectory())
        if hasattr(tracker, "save_map_outputs"):
            step = out / "map"  # with sparse.ply and topology.*
            from tqdm import tqdm

            with tqdm(desc="saving map", unit="step", disable=not progress, file=sys.stderr, leave=False) as bar:
                stats["outputs"] = tracker.save_map_outputs(out, metadata=extra_stats, progress=bar)
    except OutputError as exc:
        return str(exc)
    except OSError as exc:
        from vslam.outputs import describe_os_error

        return describe_os_error(exc, step)
    except Exception as exc:  # the trajectory and stats are safe; report it in one line, don't lose them
        log.debug("writing the map outputs failed", exc_info=True)
        return f"{out}: writing the map outputs failed ({type(exc).__name__}: {exc})"
    return None


def _adopting(tracker: Any, items: Iterator[tuple[Any, Any, float]]) -> Iterator[Any]:
    """Frames from :func:`~vslam.datasets.prefetch.prefetch_process`, each handing its prepared
    result to ``tracker.adopt_prepared`` before the tracker gets it."""
    try:
        for frame, result, seconds in items:
            if result is not None:
                tracker.adopt_prepared(frame, result, seconds)
            yield frame
    finally:
        items.close()


def trajectory_errors(trajectory: Trajectory, ground_truth: Trajectory, align: str) -> dict:
    """ATE/RPE of ``trajectory`` against ``ground_truth`` as in ``vslam eval``, the keys of
    ``stats.json`` (``ate_rmse``, ``rpe_trans_rmse``, ``rpe_rot_deg_rmse``, ``matched_poses``,
    ``scale``); {} when they do not overlap."""
    from vslam.errors import VslamError
    from vslam.eval import evaluate_trajectories

    try:
        res = evaluate_trajectories(trajectory, ground_truth, align=align)
    except VslamError as exc:
        log.warning("evaluation against ground truth skipped: %s", exc)
        return {}
    d = res.to_dict()
    return {k: d[k] for k in ("ate_rmse", "rpe_trans_rmse", "rpe_rot_deg_rmse", "matched_poses", "scale") if k in d}
