"""Writing outputs so that nothing is half-written or lost, and run folders one run at a time.

* :func:`atomic_path`: write to a temporary sibling, rename into place on success, remove it on
  failure (the old file stays whole).
* :class:`LineWriter`: a streamed text file that only ever holds whole lines (a failed write is
  cut back to the last complete line), for ``trajectory.txt``.
* :func:`open_run_dir`: check an output folder (not a file, writable, not the input), lock it
  against a second run (``filelock``), and move a previous run's outputs aside so a rerun never
  mixes old and new files; :meth:`RunDir.finish` drops them once the new run succeeded.
* :func:`check_output_file` and :func:`inside`: a single output file's path, and a path kept
  inside a folder.
"""
from __future__ import annotations

import contextlib
import errno
import logging
import os
import shutil
import uuid
from pathlib import Path
from typing import Iterator

from vslam.errors import OutputError

log = logging.getLogger(__name__)

#: Files and folders ``vslam run`` writes into a run folder (moved aside before a rerun).
RUN_OUTPUTS = ("trajectory.txt", "keyframes.txt", "stats.json", "config.yaml", "map", "sparse.ply",
               "topology.json", "topology.png", "mesh.ply", "dense.ply")
LOCK_NAME = ".vslam.lock"
PREVIOUS_NAME = ".previous-run"
_IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm", ".webp")


def describe_os_error(exc: OSError, path: str | Path | None = None) -> str:
    """``PATH: reason; what to do`` for an error writing an output."""
    where = exc.filename or path
    what = exc.strerror or str(exc)
    if exc.errno in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG):
        hint = "free space on the disk or choose another output folder"
    elif exc.errno in (errno.EACCES, errno.EPERM, errno.EROFS):
        hint = "make it writable or choose another output folder"
    else:
        hint = "choose another output folder"
    return f"{where}: cannot write ({what}); {hint}"


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary sibling of ``path`` to write; renamed onto ``path`` when the block ends
    without error, removed otherwise. ``OSError`` becomes :class:`OutputError`."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp-{uuid.uuid4().hex[:8]}")
    try:
        yield tmp
        os.replace(tmp, path)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            tmp.unlink()
        if isinstance(exc, OSError):
            raise OutputError(describe_os_error(exc, path)) from None
        raise


def atomic_write_text(path: str | Path, text: str) -> None:
    """Write ``text`` to ``path`` through :func:`atomic_path`."""
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


class LineWriter:
    """Append whole lines to a file, flushed one by one: after any failure (disk full) the file is
    cut back to its last complete line and :class:`OutputError` is raised."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._good = 0
        try:
            self._fh = open(self.path, "wb", buffering=0)
        except OSError as exc:
            raise OutputError(describe_os_error(exc, self.path)) from None

    def write(self, line: str) -> None:
        data = line.encode("utf-8")
        try:
            n = self._fh.write(data)
            if n != len(data):
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(self.path))
        except OSError as exc:
            self._cut()
            raise OutputError(describe_os_error(exc, self.path)) from None
        self._good += n

    def _cut(self) -> None:
        with contextlib.suppress(OSError):
            self._fh.truncate(self._good)

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self._fh.close()


def check_output_file(path: str | Path, what: str = "output file") -> Path:
    """``path`` as a file to write: not an existing folder, and its folder exists or can be made."""
    path = Path(path)
    if path.is_dir():
        raise OutputError(f"{path}: is a folder; give a file name for the {what}")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(describe_os_error(exc, path.parent)) from None
    return path


def inside(base: str | Path, name: str | Path) -> Path:
    """``base / name``, refusing a ``name`` that is absolute or climbs out of ``base`` (``..``)."""
    base_r = Path(base).resolve()
    target = (base_r / name).resolve()
    if target != base_r and base_r not in target.parents:
        raise OutputError(f"{name}: lies outside {base}; output names must stay inside that folder")
    return target


class RunDir:
    """A locked run folder (see :func:`open_run_dir`); use as a context manager."""

    def __init__(self, path: Path, lock, previous: Path | None) -> None:
        self.path = path
        self._lock = lock
        self.previous = previous

    def finish(self) -> None:
        """The new run is complete: drop the previous run's outputs moved aside at the start."""
        if self.previous is not None:
            shutil.rmtree(self.previous, ignore_errors=True)
            self.previous = None

    def release(self) -> None:
        if self._lock is not None:
            with contextlib.suppress(Exception):
                self._lock.release()
            self._lock = None

    def __enter__(self) -> "RunDir":
        return self

    def __exit__(self, *exc) -> None:
        self.release()


def open_run_dir(path: str | Path, inputs: tuple[str | Path, ...] = ()) -> RunDir:
    """Make ``path`` ready for a run and lock it.

    Raises :class:`OutputError` (one line naming the folder and what to do) when it is a file or
    lies under one, cannot be created or written, is (or holds the images of) an input, or another
    run holds its lock. A previous run's outputs (:data:`RUN_OUTPUTS`) are moved to
    ``.previous-run/`` so the new run never mixes with them; :meth:`RunDir.finish` removes them.
    """
    import filelock

    path = Path(path)
    if path.exists() and not path.is_dir():
        raise OutputError(f"{path}: exists and is not a folder; choose a folder for the outputs")
    for parent in path.parents:
        if parent.exists():
            if not parent.is_dir():
                raise OutputError(f"{path}: {parent} is a file, not a folder; choose another output folder")
            break
    for src in inputs:
        src_r = Path(src).resolve()
        if path.resolve() == src_r:
            raise OutputError(f"{path}: is the input; choose a separate output folder")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(describe_os_error(exc, path)) from None
    if any(p.suffix.lower() in _IMAGE_SUFFIXES and p.name not in RUN_OUTPUTS for p in path.iterdir() if p.is_file()):
        raise OutputError(f"{path}: holds images (an input folder?); choose an empty or previous run folder "
                          "for the outputs")
    probe = path / f".write-test-{uuid.uuid4().hex[:8]}"
    try:
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as exc:
        raise OutputError(describe_os_error(exc, path)) from None
    lock = filelock.FileLock(str(path / LOCK_NAME), timeout=0)
    try:
        lock.acquire()
    except filelock.Timeout:
        raise OutputError(f"{path}: another vslam run is writing into this folder; wait for it or choose "
                          "another output folder") from None
    except OSError as exc:
        raise OutputError(describe_os_error(exc, path)) from None
    try:
        previous = _move_previous(path)
    except OSError as exc:
        lock.release()
        raise OutputError(describe_os_error(exc, path)) from None
    return RunDir(path, lock, previous)


def _move_previous(path: Path) -> Path | None:
    old = [path / n for n in RUN_OUTPUTS if (path / n).exists() or (path / n).is_symlink()]
    if not old:
        return None
    prev = path / PREVIOUS_NAME
    if prev.exists():
        shutil.rmtree(prev, ignore_errors=True)
    prev.mkdir()
    for p in old:
        os.replace(p, prev / p.name)
    log.info("%s: the previous run's outputs were moved to %s", path, prev)
    return prev
