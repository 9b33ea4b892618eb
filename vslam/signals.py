"""Stopping cleanly: SIGTERM handled like Ctrl-C, and child processes that never outlive their parent.

* :func:`terminate_as_interrupt` makes SIGTERM (and SIGHUP) raise :class:`Interrupted`, a
  :class:`KeyboardInterrupt`, in the main thread, so the run loop's ``except KeyboardInterrupt`` /
  ``finally`` blocks write ``stats.json`` and stop the prefetch process exactly as on Ctrl-C.
* :func:`watch_parent` (called in a child process) exits the child once its parent is gone
  (``os.getppid()`` changes when the parent dies, even by SIGKILL), so nothing is left running.
"""
from __future__ import annotations

import os
import signal
import threading
from typing import Any


class Interrupted(KeyboardInterrupt):
    """The process was asked to stop by a signal (``signum``); exit status ``128 + signum``."""

    def __init__(self, signum: int = signal.SIGINT) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = int(signum)

    @property
    def reason(self) -> str:
        return "interrupted" if self.signum == signal.SIGINT else f"terminated ({signal.Signals(self.signum).name})"


def _raise_interrupted(signum: int, frame: Any) -> None:
    raise Interrupted(signum)


def terminate_as_interrupt(signals: tuple[str, ...] = ("SIGTERM", "SIGHUP")) -> bool:
    """Install handlers raising :class:`Interrupted` for ``signals``; only from the main thread
    (returns False elsewhere, leaving the handlers alone)."""
    if threading.current_thread() is not threading.main_thread():
        return False
    for name in signals:
        sig = getattr(signal, name, None)
        if sig is not None:
            signal.signal(sig, _raise_interrupted)
    return True


def exit_status(exc: BaseException) -> int:
    """``128 + signal number`` for an interrupt (130 for Ctrl-C, 143 for SIGTERM)."""
    return 128 + (exc.signum if isinstance(exc, Interrupted) else int(signal.SIGINT))


def interrupt_reason(exc: BaseException) -> str:
    """``interrupted`` (Ctrl-C) or ``terminated (SIGTERM)``, for ``stats.json``'s ``error``."""
    return exc.reason if isinstance(exc, Interrupted) else "interrupted"


def watch_parent(interval: float = 0.25, parent_pid: int | None = None) -> threading.Thread:
    """(child process) Exit this process (``os._exit(1)``) as soon as its parent is gone: a daemon
    thread polls ``os.getppid()``, which changes when the parent dies (reparenting to init or a
    subreaper), however it died."""
    parent = os.getppid() if parent_pid is None else parent_pid

    def poll() -> None:
        stop = threading.Event()
        while not stop.wait(interval):
            if os.getppid() != parent:
                os._exit(1)

    thread = threading.Thread(target=poll, name="vslam-watch-parent", daemon=True)
    thread.start()
    return thread
