"""Hand keyframes from tracking to a backend stage (local mapping, loop closing).

Two modes, as ``backend.mode``:

- deterministic: :meth:`KeyframeQueue.put` only queues; the owner calls :meth:`run_pending` after
  each frame, so the stage runs inline and every run gives the same result.
- realtime: a daemon worker thread (at a lower OS priority than tracking, so tracking wins the CPU
  when the cores are busy) handles the ids as they arrive, as ORB-SLAM's LocalMapping and
  LoopClosing threads do. ``newest_only`` lets a stage that piles up skip to the newest keyframe
  (local BA: the newest window holds the skipped keyframes).
"""
from __future__ import annotations

import logging
import os
import queue
import threading
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
