"""Decode frames ahead of the tracker in a background thread (a bounded producer-consumer queue).

Image decoding (:mod:`vslam.datasets.png`'s inflate and kernel, or ``cv2.imdecode``) releases
the GIL, so on a machine with two or more cores the next frames are decoded while the current one
is tracked; at most ``depth`` decoded frames wait in the queue, so memory stays flat however long
the sequence.

The wrapped iterator keeps the reader's semantics: frames come in the same order, a corrupt
frame the reader skips is still skipped (and counted by the reader), and an exception the reader
raises reaches the consumer after the frames decoded before it, at the same position it would
have without prefetching. Closing the returned iterator (or dropping it) stops the thread.

:func:`prefetch_process` does the same in a child *process* for a :class:`FrameRange` (a picklable
dataset slice): decoding and the per-frame ``work`` (e.g. feature detection) then run outside this
interpreter, so they never compete with the tracker for the GIL. It starts a fresh interpreter
(``spawn``, about a second), so :func:`choose_prefetch` picks it only for long runs (by the pixels
to read), on two or more cores, when the main module is safe to import again in the child.

Example:
    >>> for frame in prefetch(ds.frames(), depth=4):     # doctest: +SKIP
    ...     system.track(frame)
"""
from __future__ import annotations

import logging
import os
import pickle
import queue
import sys
import threading
import time
from typing import Any, Callable, Iterable, Iterator, TypeVar

log = logging.getLogger(__name__)

T = TypeVar("T")

_END = object()


class _Raised:
    """An exception raised by the source iterator, delivered in order."""

    __slots__ = ("exc",)

    def __init__(self, exc: BaseException) -> None:
        self.exc = exc


# The thread prepares an item only while this many items wait for the consumer ahead of it: with
# one, the consumer (tracking a prepared frame takes ~3 ms) ran dry while the thread spent ~10 ms
# on the next frame's detection and stereo, idle ~2.5 ms a frame. Measured on a quiet 2-core
# machine, whole-run frames/s with 1 -> 2: EuRoC V101 40 stereo frames 93.1 -> 101.6, KITTI 06
# 53.4 -> 53.5, fr1 desk 9 RGB-D 73.6-78.4 -> 78.6-79.1, KITTI 07 mono 86.3-88.1 -> 87.7-88.5;
# 3 was no better than 2 (EuRoC 100.1). Which frames are prepared where never changes the results.
BALANCE_LEAD = 2


def prefetch(items: Iterable[T], depth: int = 4, prepare: Callable[[T], object] | None = None,
             balance: bool = True) -> Iterator[T]:
    """Yield ``items`` while a daemon thread produces up to ``depth`` of them ahead.

    ``prepare(item)``, when given, is called on items in that thread before they are queued
    (per-frame work that needs no tracking state and that the consumer otherwise does itself, e.g.
    :meth:`vslam.frontend.tracker.Tracker.prepare`); an exception it raises reaches the consumer
    like the reader's own. With ``balance`` it is skipped unless at least :data:`BALANCE_LEAD`
    items already wait in the queue (the consumer is, or soon will be, waiting: hand the item
    over at once and let the consumer do that work), so the work splits between the two threads
    by itself whichever is slower; otherwise every item is prepared. ``depth <= 0`` returns the
    plain iterator (no thread, no ``prepare``).
    """
    if depth <= 0:
        yield from items
        return
    q: queue.Queue = queue.Queue(maxsize=depth)
    stop = threading.Event()

    def put(item) -> bool:
        return _put_until_stopped(q, item, stop)

    def work() -> None:
        it = iter(items)
        try:
            while not stop.is_set():
                try:
                    item = next(it)
                except StopIteration:
                    break
                if prepare is not None and (not balance or q.qsize() >= BALANCE_LEAD):
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


class FrameRange:
    """Frames ``start .. stop - 1`` of a dataset: iterates like ``dataset.frames(start, stop)`` and
    pickles (with its dataset), so a prefetch process can read the frames itself."""

    def __init__(self, dataset: Any, start: int = 0, stop: int | None = None) -> None:
        self.dataset = dataset
        self.start = start
        self.stop = len(dataset) if stop is None else stop

    def __iter__(self) -> Iterator[Any]:
        return iter(self.dataset.frames(self.start, self.stop))

    def __len__(self) -> int:
        return max(0, self.stop - self.start)


PREFETCH_MODES = ("auto", "thread", "process", "none")
# Pixels to read and prepare (frames x pixels x images per frame) below which starting an interpreter
# (~1-1.6 s of CPU) costs more than it saves. Measured (prefetch process vs thread, A/B back to back
# on a loaded 2-core machine, with the stereo depth prepared ahead): EuRoC 40 stereo frames (29 M)
# 5.0-7.0 vs 11.3-12.4 frames/s, KITTI 06 51 stereo frames (46 M) 5.8-6.8 vs 7.1-8.2, KITTI 07
# 160 mono frames (73 M) 6.3-7.7 vs 7.9-9.2; 7-Scenes' first 300 RGB-D frames (184 M) 6.55 vs 5.75.
PROCESS_MIN_PIXELS = 150_000_000
PROCESS_HEAD_FRAMES = 30  # read by the consumer itself while the child starts (~1 s at 30 frames/s)


def _main_is_reimportable() -> bool:
    """Whether a ``spawn`` child may import this program's main module again without re-running
    it: interactive sessions, ``python -c`` and ``python -m`` are never re-run; a script only when
    it guards its work with ``if __name__ == "__main__"`` (pip's console scripts, ``vslam``, do)."""
    main = sys.modules.get("__main__")
    if main is None or getattr(main, "__spec__", None) is not None:
        return True
    path = getattr(main, "__file__", None)
    if not path:
        return True
    try:
        with open(path, encoding="utf-8", errors="replace") as fh:
            src = fh.read()
    except OSError:
        return False
    return "__name__" in src and "__main__" in src


def _picklable(obj: Any) -> bool:
    try:
        pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)
    except Exception:  # e.g. a reader holding an open video capture
        log.debug("%r cannot be sent to a process; prefetching in a thread", obj)
        return False
    return True


def choose_prefetch(mode: str, frames: Any, total: int | None) -> str:
    """Resolve ``mode`` (one of :data:`PREFETCH_MODES`) for ``frames``: ``auto`` is ``process``
    for a :class:`FrameRange` of at least :data:`PROCESS_MIN_PIXELS` pixels (frames x
    :func:`_pixels_per_frame`) on a machine with two or more cores, from a non-daemonic process whose main module is safe to import again, else
    ``thread``; ``process`` falls back to ``thread`` when ``frames`` cannot be sent to a process or
    the main script would run again in the child (no ``__main__`` guard: the child died there and the
    run waited on it for ever)."""
    import multiprocessing

    if mode not in PREFETCH_MODES:
        from vslam.errors import ConfigError

        raise ConfigError(f"prefetch mode {mode!r} is not one of {', '.join(PREFETCH_MODES)}")
    if mode in ("thread", "none"):
        return mode
    ok = isinstance(frames, FrameRange) and not multiprocessing.current_process().daemon and _picklable(frames)
    if mode == "process":
        if ok and not _main_is_reimportable():  # its child would run the script again and die: never hang on it
            log.warning("prefetch=process: the main script has no `if __name__ == \"__main__\"` guard, so a "
                        "child process would run it again; prefetching in a thread")
            return "thread"
        return "process" if ok else "thread"
    n = total if total is not None else len(frames) if ok else 0
    long_run = ok and n * _pixels_per_frame(frames.dataset) >= PROCESS_MIN_PIXELS
    if long_run and (os.cpu_count() or 1) >= 2 and _main_is_reimportable():
        return "process"
    return "thread"


def _pixels_per_frame(dataset: Any) -> int:
    """Pixels of one frame's images: the camera's ``width x height``, twice for a stereo pair or a
    depth image (the sensor the dataset reads); a VGA image when the dataset does not say."""
    cam = getattr(dataset, "camera", None)
    w, h = getattr(cam, "width", None), getattr(cam, "height", None)
    pixels = int(w) * int(h) if w and h else 640 * 480
    return pixels * (1 if getattr(dataset, "sensor", "mono") == "mono" else 2)


def _put_until_stopped(q, item, stop) -> bool:
    """``q.put(item)``, giving up (False) once ``stop`` is set (a thread or process Event)."""
    while not stop.is_set():
        try:
            q.put(item, timeout=0.1)
            return True
        except queue.Full:
            continue
    return False


class _Slots:
    """Shared-memory slots carrying the large arrays of a message from the child to the consumer.

    A message is pickled with protocol 5 and its contiguous buffers (the images, depth and
    descriptor arrays) out of band (PEP 574); the child copies those into a free slot and queues
    only the small pickle and the buffer spans, the consumer copies them out and frees the slot.
    Through the queue's pipe alone a 640x480 RGB-D frame (2.5 MB) took ~8 ms per side; this way
    two ``memcpy`` calls. Messages larger than a slot go through the queue as they are."""

    def __init__(self, ctx, n_slots: int, slot_bytes: int) -> None:
        self.arrays = [ctx.RawArray("B", slot_bytes) for _ in range(n_slots)]
        self.free = ctx.Queue()
        for i in range(n_slots):
            self.free.put(i)
        self.slot_bytes = slot_bytes
        self._views = None

    def __getstate__(self) -> dict:
        return {"arrays": self.arrays, "free": self.free, "slot_bytes": self.slot_bytes, "_views": None}

    def views(self) -> list:
        if self._views is None:
            import numpy as np

            self._views = [np.frombuffer(a, np.uint8) for a in self.arrays]
        return self._views

    def pack(self, msg: tuple, stop) -> tuple | None:
        """(child) ``msg`` as ``("shm", slot, pickle, spans)``, or ``msg`` itself when too large;
        None when the consumer stopped while no slot was free."""
        import numpy as np

        bufs: list = []
        data = pickle.dumps(msg, protocol=5, buffer_callback=bufs.append)
        raws = [b.raw() for b in bufs]
        if sum(r.nbytes for r in raws) > self.slot_bytes:
            return msg
        while True:
            try:
                slot = self.free.get(timeout=0.1)
                break
            except queue.Empty:
                if stop.is_set():
                    return None
        view, off, spans = self.views()[slot], 0, []
        for r in raws:
            n = r.nbytes
            view[off:off + n] = np.frombuffer(r, np.uint8)
            spans.append((off, n))
            off += n
        return ("shm", slot, data, spans)

    def unpack(self, msg: tuple) -> tuple:
        """(consumer) the original message of a ``pack`` result; frees its slot."""
        if msg[0] != "shm":
            return msg
        _, slot, data, spans = msg
        view = self.views()[slot]
        bufs = [bytearray(view[o:o + n]) for o, n in spans]  # own, writable copies
        self.free.put(slot)
        return pickle.loads(data, buffers=bufs)


def _slot_bytes(source: FrameRange) -> int | None:
    """Room for one frame and its prepared features: 1.5x the arrays of the first frame plus 2 MB
    (frames of a sequence share their size); None when the first frame cannot be read here (the
    child then reports that in order)."""
    try:
        first = next(iter(source.dataset.frames(source.start, min(source.start + 1, source.stop))))
    except Exception:
        return None
    n = sum(getattr(a, "nbytes", 0) for a in (first.image, first.image_right, first.depth) if a is not None)
    return int(1.5 * n) + (2 << 20)


def _child_main(source: FrameRange, work: Callable[[Any], Any] | None, q, stop, waiting,
                slots: _Slots | None = None) -> None:
    """Body of the prefetch process: read, ``work`` on and queue every frame, in order; ``work``
    is skipped (result None) while ``waiting`` (a shared flag, or None) says the consumer waits.
    The process exits by itself once its parent is gone (:func:`vslam.signals.watch_parent`)."""
    from vslam.signals import watch_parent

    watch_parent()
    try:
        import cv2

        cv2.setNumThreads(1)  # one core for this process; the tracker has the other
    except Exception:  # pragma: no cover - OpenCV is a dependency
        pass
    try:
        for frame in source:
            if stop.is_set():
                break
            t0 = time.perf_counter()
            # skip the work when the consumer waits (flag) or is about to (nothing queued)
            idle = waiting is not None and (waiting.value or q.qsize() == 0)
            result = work(frame) if work is not None and not idle else None
            msg = ("frame", frame, result, time.perf_counter() - t0)
            if slots is not None:
                msg = slots.pack(msg, stop)
            if msg is None or not _put_until_stopped(q, msg, stop):
                break
        if stop.is_set():  # the consumer stopped: exit without flushing what it will never read
            q.cancel_join_thread()
            return
    except BaseException as exc:  # noqa: BLE001 - delivered to the consumer in order
        try:
            pickle.dumps(exc)
        except Exception:
            from vslam.errors import DatasetError

            exc = DatasetError(f"{type(exc).__name__}: {exc}")
        _put_until_stopped(q, ("raise", exc), stop)
        return
    _put_until_stopped(q, ("end",), stop)


def prefetch_process(source: FrameRange, work: Callable[[Any], Any] | None = None,
                     depth: int = 4, balance: bool = True, head: int = 0) -> Iterator[tuple[Any, Any, float]]:
    """Yield ``(frame, work(frame), seconds of work)`` for the frames of ``source``, read and
    worked on ahead in a child process (at most ``depth`` waiting).

    The first ``head`` frames are read here instead, by a thread as in :func:`prefetch` that also
    does the ``work`` on them (balanced the same way), while the child starts (a new interpreter
    takes about a second, in which the consumer would otherwise idle); the child begins at the
    frame after them.

    With ``balance``, ``work`` is skipped (result None) for a frame the consumer is already
    waiting for (a shared flag it sets while blocked on an empty queue): the consumer then does
    that work itself, so the work splits between the two processes by itself whichever is
    slower, and the consumer takes it on only when it would otherwise idle.

    ``work`` must be picklable (e.g. :class:`vslam.frontend.prepare.FramePreparer`). Order,
    skipped corrupt frames and a reader's exception (raised here, after the frames read before
    it) are as with :func:`prefetch`. Closing the iterator stops the process.

    Raises:
        DatasetError: the process died without reporting an error (e.g. killed for memory).
    """
    import multiprocessing

    head = max(0, min(int(head), len(source)))
    rest = FrameRange(source.dataset, source.start + head, source.stop)
    if len(rest) == 0:  # all head: no child
        yield from _head_in_thread(source, work, depth, balance)
        return
    ctx = multiprocessing.get_context("spawn")
    q = ctx.Queue(maxsize=max(1, depth))
    stop = ctx.Event()
    waiting = ctx.RawValue("b", 0) if balance else None
    size = _slot_bytes(rest)
    slots = _Slots(ctx, max(1, depth) + 2, size) if size else None
    proc = ctx.Process(target=_child_main, args=(rest, work, q, stop, waiting, slots), name="vslam-prefetch",
                       daemon=True)
    # start() blocks until the child has read its arguments: in a thread, while the head is read here
    starter, start_error = _start_in_thread(proc)
    try:
        if head:
            yield from _head_in_thread(FrameRange(source.dataset, source.start, rest.start), work, depth, balance)
        starter.join()
        if start_error:
            raise start_error[0]
        while True:
            msg = _receive(q, proc, waiting)
            if slots is not None:
                msg = slots.unpack(msg)
            if msg[0] == "end":
                return
            if msg[0] == "raise":
                raise msg[1]
            yield msg[1], msg[2], msg[3]
    finally:
        _shut_down(proc, starter, q, stop, slots)


class _Item:
    """A frame on its way through :func:`_head_in_thread` with its ``work`` result (None: not done)."""

    __slots__ = ("frame", "result", "seconds")

    def __init__(self, frame: Any) -> None:
        self.frame, self.result, self.seconds = frame, None, 0.0


def _head_in_thread(head: FrameRange, work: Callable[[Any], Any] | None, depth: int,
                    balance: bool) -> Iterator[tuple[Any, Any, float]]:
    """``(frame, work(frame) or None, seconds)`` for the frames of ``head``, read and worked on ahead
    in a thread (:func:`prefetch`, same balance)."""

    def prepare(item: _Item) -> None:
        t0 = time.perf_counter()
        item.result = work(item.frame)
        item.seconds = time.perf_counter() - t0

    items = prefetch((_Item(f) for f in head), depth, prepare if work is not None else None, balance)
    try:
        for item in items:
            yield item.frame, item.result, item.seconds
    finally:
        items.close()


def _start_in_thread(proc) -> tuple[threading.Thread, list[BaseException]]:
    """Start ``proc`` in a thread (``start()`` blocks until the child has read its arguments);
    returns the thread and the list that receives a start error, for the consumer to re-raise."""
    start_error: list[BaseException] = []

    def start() -> None:
        try:
            proc.start()
        except BaseException as exc:  # noqa: BLE001 - re-raised in the consumer
            start_error.append(exc)

    starter = threading.Thread(target=start, name="vslam-prefetch-start", daemon=True)
    starter.start()
    return starter, start_error


def _receive(q, proc, waiting) -> tuple:
    """The child's next message; the shared ``waiting`` flag is set while the queue is empty.

    Raises:
        DatasetError: the process exited without a last message (e.g. killed for memory).
    """
    from vslam.errors import DatasetError

    while True:
        if waiting is not None and q.empty():
            waiting.value = 1
        try:
            msg = q.get(timeout=0.5)
        except queue.Empty:
            if proc.is_alive():
                continue
            try:
                msg = q.get(timeout=0.5)  # anything it queued just before exiting
            except queue.Empty:
                raise DatasetError(
                    f"the frame-reading process exited with code {proc.exitcode} without "
                    "finishing; rerun (it may have run out of memory)"
                ) from None
        if waiting is not None:
            waiting.value = 0
        return msg


def _shut_down(proc, starter: threading.Thread, q, stop, slots) -> None:
    """Stop the child (asked, then terminated after 3 s) and close the queues without joining their feeders."""
    stop.set()
    starter.join()
    if proc.pid is not None:
        proc.join(timeout=3.0)
    if proc.is_alive():
        proc.terminate()
        proc.join(timeout=2.0)
    q.cancel_join_thread()
    q.close()
    if slots is not None:
        slots.free.cancel_join_thread()
        slots.free.close()
