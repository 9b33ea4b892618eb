"""Hand keyframes from tracking to a backend stage (local mapping, loop closing).

Two modes, as ``backend.mode``:

- deterministic: :meth:`KeyframeQueue.put` only queues; the owner calls :meth:`run_pending` after
  each frame, so the stage runs inline and every run gives the same result.
- realtime: a daemon worker thread (at a lower OS priority than tracking, so tracking wins the CPU
  when the cores are busy) handles the ids as they arrive, as ORB-SLAM's LocalMapping and
  LoopClosing threads do. ``newest_only`` lets a stage that piles up skip to the newest keyframe
  (local BA: the newest window holds the skipped keyframes).
- parallel (:class:`LaggedQueue`): the stage's heavy middle step (local BA's solve) runs in a worker
  thread while tracking goes on, and its result is applied at a fixed frame lag, so every run gives
  the same result.
"""
from __future__ import annotations

import logging
import os
import queue
import threading
import time
from typing import Callable

log = logging.getLogger(__name__)


class KeyframeQueue:
    """Keyframe ids for ``handle(kf_id)``, inline (:meth:`run_pending`) or in a worker thread.

    Args:
        handle: the stage's work for one keyframe id.
        realtime: run ``handle`` in a background thread instead of inline.
        name: the worker thread's name (shown in profilers and logs).
        newest_only: realtime: of the ids waiting when the worker is free, handle only the newest
            (the others are counted in :attr:`skipped`).
    """

    def __init__(self, handle: Callable[[int], object], realtime: bool, name: str, newest_only: bool = False) -> None:
        self.handle = handle
        self.realtime = bool(realtime)
        self.name = name
        self.newest_only = newest_only
        self.skipped = 0
        self.failed = 0  # worker exceptions (logged; a worker must never die silently)
        self._pending: list[int] = []
        self._queue: queue.Queue = queue.Queue()
        self._thread: threading.Thread | None = None

    def put(self, kf_id: int) -> None:
        """Queue ``kf_id`` (starting the worker on first use in realtime mode)."""
        if not self.realtime:
            self._pending.append(kf_id)
            return
        if self._thread is None:
            self._thread = threading.Thread(target=self._worker, name=self.name, daemon=True)
            self._thread.start()
        self._queue.put(kf_id)

    def run_pending(self) -> None:
        """Deterministic mode: handle the queued ids inline, oldest first."""
        while self._pending:
            self.handle(self._pending.pop(0))

    def finish(self) -> None:
        """Handle what is queued (deterministic) or drain and join the worker (realtime)."""
        self.run_pending()
        if self._thread is not None:
            self._queue.put(None)
            self._thread.join()
            self._thread = None

    def _next(self) -> int | None:
        kf_id = self._queue.get()
        if kf_id is None or not self.newest_only:
            return kf_id
        while True:  # ids that piled up meanwhile: keep the newest
            try:
                nxt = self._queue.get_nowait()
            except queue.Empty:
                return kf_id
            if nxt is None:
                self._queue.put(None)  # finish() after the newest one
                return kf_id
            self.skipped += 1
            kf_id = nxt

    def _worker(self) -> None:
        try:  # Linux: per-thread niceness
            os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), 10)
        except (AttributeError, OSError):
            pass
        while True:
            kf_id = self._next()
            if kf_id is None:
                return
            try:
                self.handle(kf_id)
            except Exception:
                self.failed += 1
                log.exception("%s failed on keyframe %d", self.name, kf_id)


def _can_spawn() -> bool:
    """A ``spawn`` child is possible: not from a daemonic process, and the main module imports
    again without re-running (see :func:`vslam.datasets.prefetch.choose_prefetch`)."""
    import multiprocessing

    from vslam.datasets.prefetch import _main_is_reimportable

    return not multiprocessing.current_process().daemon and _main_is_reimportable()


class LaggedQueue:
    """``backend.mode=parallel``: a keyframe's work in three steps, the middle one in a worker thread,
    the result used at a fixed point of the frame sequence, so every run gives the same result.

    ``prepare(kf_id) -> job | None`` runs in the caller's (tracking) thread at the end of the frame
    that brought the keyframe (a snapshot of the map: the job holds copies), ``solve(job) -> result``
    in the worker thread while the next frames are tracked (it must touch only the job), and
    ``finish(job, result)`` in the caller's thread at the end of the ``lag_frames``-th frame after,
    or at the end of a frame that brought another keyframe when that comes first, waiting for the
    worker if it is not done: where results enter the map depends on the frame count, never on
    timing. ``done(kf_id)`` follows each keyframe's ``finish`` (or ``prepare`` returning None).
    One job is in flight at a time; keyframes are handled oldest first.

    With ``worker="process"`` the worker is a child process (``spawn``, started at the first
    keyframe; ``solve`` and the jobs must pickle): tracking and the solve then never compete for
    the GIL (a solve's NumPy calls hand the GIL back and forth with the tracking thread's Python
    code, each hand-over waiting up to the 5 ms switch interval).

    Args:
        prepare, solve, finish, done: the steps (see above).
        lag_frames: frames between a job's ``prepare`` and its ``finish`` (>= 1).
        name: the worker thread's name.
        worker: ``thread`` or ``process``.
        warm: process worker: a picklable callable run in the child at start (imports, compiled kernels).
    """

    def __init__(self, prepare: Callable[[int], object], solve: Callable[[object], object],
                 finish: Callable[[object, object], object], done: Callable[[int], None], lag_frames: int,
                 name: str, worker: str = "thread", warm: Callable[[], object] | None = None) -> None:
        self.prepare, self.solve, self.finish_job, self.done = prepare, solve, finish, done
        self.lag_frames = max(1, int(lag_frames))
        self.name = name
        self.worker = worker
        self.warm = warm
        self.failed = 0
        self.wait_s = 0.0  # time the caller waited for the worker at a settle point
        self._pending: list[int] = []
        self._inflight: tuple[int, object, object] | None = None  # (kf_id, job, future)
        self._frames = 0
        self._executor = None

    def put(self, kf_id: int) -> None:
        """Queue ``kf_id``; its ``prepare`` runs in :meth:`run_pending`."""
        self._pending.append(kf_id)
        if self._executor is None:
            self._executor = self._start()

    def _start(self):
        if self.worker == "process" and not _can_spawn():
            log.info("%s: a child process cannot be started from here; solving in a thread", self.name)
            self.worker = "thread"
        if self.worker != "process":
            from concurrent.futures import ThreadPoolExecutor

            return ThreadPoolExecutor(max_workers=1, thread_name_prefix=self.name)
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor

        from vslam.signals import watch_parent

        ex = ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("spawn"),
                                 initializer=watch_parent)
        if self.warm is not None:
            ex.submit(self.warm)  # the child starts (imports) while the first frames are tracked
        return ex

    def run_pending(self) -> None:
        """End of a frame: settle the job in flight when its lag is reached (or a keyframe waits),
        then prepare the waiting keyframes; the newest goes to the worker, older ones (only when
        several arrived in one frame) are solved inline."""
        if self._inflight is not None:
            self._frames += 1
            if self._frames >= self.lag_frames or self._pending:
                self.settle()
        while self._pending:
            kf_id = self._pending.pop(0)
            job = self.prepare(kf_id)
            if job is None:
                self.done(kf_id)
            elif self._pending:
                self.finish_job(job, self.solve(job))
                self.done(kf_id)
            else:
                self._inflight = (kf_id, job, self._executor.submit(self.solve, job))
                self._frames = 0

    def settle(self) -> None:
        """Wait for the job in flight (if any) and finish it."""
        if self._inflight is None:
            return
        kf_id, job, future = self._inflight
        self._inflight = None
        t0 = time.perf_counter()
        try:
            result = future.result()
        except Exception:
            self.failed += 1
            log.exception("%s failed on keyframe %d", self.name, kf_id)
            result = None
        self.wait_s += time.perf_counter() - t0
        if result is not None:
            self.finish_job(job, result)
        self.done(kf_id)

    def finish(self) -> None:
        """End of input: settle, handle what is queued, stop the worker."""
        self.settle()
        while self._pending or self._inflight is not None:
            self.run_pending()
            self.settle()
        if self._executor is not None:
            self._executor.shutdown(wait=True)
            self._executor = None
