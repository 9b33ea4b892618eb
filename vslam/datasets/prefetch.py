"""Decode frames ahead of the tracker in a background thread (a bounded producer-consumer queue).

Image decoding (``cv2.imdecode``) releases the GIL, so on a machine with two or more cores the
next frames are decoded while the current one is tracked; at most ``depth`` decoded frames wait
in the queue, so memory stays flat however long the sequence.

The wrapped iterator keeps the reader's semantics: frames come in the same order, a corrupt
frame the reader skips is still skipped (and counted by the reader), and an exception the reader
raises reaches the consumer after the frames decoded before it, at the same position it would
have without prefetching. Closing the returned iterator (or dropping it) stops the thread.

Example:
    >>> for frame in prefetch(ds.frames(), depth=4):     # doctest: +SKIP
    ...     system.track(frame)
"""
from __future__ import annotations

import logging
import queue
import threading
from typing import Callable, Iterable, Iterator, TypeVar

log = logging.getLogger(__name__)

T = TypeVar("T")

_END = object()


class _Raised:
    """An exception raised by the source iterator, delivered in order."""

    __slots__ = ("exc",)

    def __init__(self, exc: BaseException) -> None:
        self.exc = exc


def prefetch(items: Iterable[T], depth: int = 4, prepare: Callable[[T], object] | None = None,
             balance: bool = True) -> Iterator[T]:
    """Yield ``items`` while a daemon thread produces up to ``depth`` of them ahead.

    ``prepare(item)``, when given, is called on items in that thread before they are queued
    (per-frame work that needs no tracking state and that the consumer otherwise does itself, e.g.
    :meth:`vslam.frontend.tracker.Tracker.prepare`); an exception it raises reaches the consumer
    like the reader's own. With ``balance`` it is skipped while the queue is empty (the consumer
    is waiting: hand the item over at once and let the consumer do that work), so the work
    splits between the two threads by itself whichever is slower; otherwise every item is
    prepared. ``depth <= 0`` returns the plain iterator (no thread, no ``prepare``).
    """
    if depth <= 0:
        yield from items
        return
    q: queue.Queue = queue.Queue(maxsize=depth)
    stop = threading.Event()

    def put(item) -> bool:
        while not stop.is_set():
            try:
                q.put(item, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def work() -> None:
        it = iter(items)
        try:
            while not stop.is_set():
                try:
                    item = next(it)
                except StopIteration:
                    break
                if prepare is not None and (not balance or q.qsize() > 0):
                    prepare(item)
                if not put(item):
                    return
        except BaseException as exc:  # noqa: BLE001 - re-raised in the consumer
            put(_Raised(exc))
            return
        finally:
            close = getattr(it, "close", None)
            if close is not None and stop.is_set():
                try:
                    close()
                except Exception:  # pragma: no cover - closing a generator never matters here
                    log.debug("closing the prefetched iterator failed", exc_info=True)
        put(_END)

    thread = threading.Thread(target=work, name="vslam-prefetch", daemon=True)
    thread.start()
    try:
        while True:
            item = q.get()
            if item is _END:
                return
            if isinstance(item, _Raised):
                raise item.exc
            yield item
    finally:
        stop.set()
        thread.join(timeout=5.0)
