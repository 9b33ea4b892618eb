"""Writing outputs so that nothing is half-written or lost, and run folders one run at a time.

* :func:`atomic_path`: write to a temporary sibling (same folder), ``fsync`` it, rename it into
  place on success, remove it on failure (the old file stays whole). :func:`atomic_write_bytes` /
  :func:`atomic_write_text`: the same for bytes made in memory (plots, vocabularies, reports); every
  command writes its files through these.
* :class:`LineWriter`: a streamed text file that only ever holds whole lines (a failed write is
  cut back to the last complete line), for ``trajectory.txt``.
* :func:`open_run_dir`: check an output folder (not a file, writable, not the input), lock it
  against a second run (``filelock``), and move a previous run's outputs aside so a rerun never
  mixes old and new files; ``.previous-run/`` always keeps the last complete run, and only
  :meth:`RunDir.finish` (the new run succeeded) drops it.
* :func:`check_output_file`, :func:`refuse_inputs` and :func:`inside`: a single output file's path,
  an output that would land on one of the command's inputs, and a path kept inside a folder.
* :func:`reading_run_dir`: a command reading a run folder (a map) while another writes it (``vslam run
  --map M -o M``) waits for it, a bounded time, then says which command it is (``.vslam.lock.owner``);
  :func:`last_complete_run`: where the last complete run of a folder is (``.previous-run/`` after a
  stopped rerun).
"""
from __future__ import annotations

import contextlib
import errno
import json
import logging
import math
import os
import shlex
import shutil
import sys
import time
import uuid
from pathlib import Path
from typing import Iterable, Iterator

from vslam.errors import OutputError

log = logging.getLogger(__name__)

#: Files and folders ``vslam run`` (and ``merge`` / ``localize``) write into a run folder (moved
#: aside before a rerun).
RUN_OUTPUTS = ("trajectory.txt", "trajectory.png", "keyframes.txt", "stats.json", "config.yaml", "map", "sparse.ply",
               "topology.json", "topology.png", "mesh.ply", "dense.ply", "trajectory_kitti.txt",
               "trajectory_kitti_times.txt", "trajectory_euroc.csv", "merge.png", "imu_states.csv")
LOCK_NAME = ".vslam.lock"
OWNER_NAME = ".vslam.lock.owner"  # who holds the lock: command line, pid, since when (JSON)
#: seconds a command reading a run folder (a map) waits for the command writing it
READ_WAIT_S = 20.0
PREVIOUS_NAME = ".previous-run"
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm", ".webp")
_CHUNK = 1 << 20

#: why an output cannot be written, and what to do, by ``errno``
_HINTS = {
    errno.ENOSPC: "free space on the disk or choose another output folder",
    errno.EDQUOT: "the disk quota is used up; free space on the disk or choose another output folder",
    errno.EFBIG: "the file is larger than allowed (ulimit -f or the file system's limit); raise the limit or "
                 "choose another output folder",
    errno.EROFS: "the file system is read-only; choose an output folder on a writable one",
    errno.EACCES: "make it writable or choose another output folder",
    errno.EPERM: "make it writable or choose another output folder",
    errno.ENAMETOOLONG: "the path or a name in it is too long; choose a shorter output path",
    errno.ENOENT: "a folder on the path does not exist; create it or choose another output path",
    errno.ENOTDIR: "a part of the path is a file, not a folder; choose another output path",
    errno.EISDIR: "it is a folder; give a file name",
    errno.ELOOP: "the path runs through a symbolic link loop; choose another output path",
}


def os_error_hint(exc: OSError, default: str = "choose another output folder") -> str:
    """What to do about ``exc`` (by its ``errno``): never "free space" unless the disk is full."""
    return _HINTS.get(exc.errno, default)


def _temporary(name: object) -> bool:
    return ".tmp-" in str(name) or ".write-test-" in str(name)


def describe_os_error(exc: OSError, path: str | Path | None = None) -> str:
    """``PATH: cannot write (reason); what to do`` for an error writing an output. ``PATH`` is the
    file the error names unless that is one of our temporary files (then ``path``, the target)."""
    where = exc.filename if exc.filename and not (_temporary(exc.filename) and path is not None) else path
    what = exc.strerror or str(exc)
    return f"{where}: cannot write ({what}); {os_error_hint(exc)}"


def _fsync(path: Path, directory: bool = False) -> None:
    """Flush ``path`` to the disk (a folder: its entries); file systems without fsync are let be."""
    try:
        fd = os.open(path, os.O_RDONLY | (getattr(os, "O_DIRECTORY", 0) if directory else 0))
    except OSError:
        if directory:
            return
        raise
    try:
        os.fsync(fd)
    except OSError as exc:
        if exc.errno not in (errno.EINVAL, errno.ENOTSUP, errno.EBADF) and not directory:
            raise
    finally:
        os.close(fd)


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary sibling of ``path`` to write (same folder, same suffix); flushed to the disk
    and renamed onto ``path`` when the block ends without error, removed otherwise. ``OSError``
    becomes :class:`OutputError` naming ``path``."""
    path = Path(path)
    # (the name cut so that a target name near the file system's 255-byte limit still has a sibling)
    tmp = path.with_name(f".{path.name[:200]}.tmp-{uuid.uuid4().hex[:8]}{path.suffix[:16]}")
    try:
        yield tmp
        if tmp.is_file():
            _fsync(tmp)
        os.replace(tmp, path)
        _fsync(path.parent, directory=True)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            tmp.unlink()
        if isinstance(exc, OSError):
            raise OutputError(describe_os_error(exc, path)) from None
        raise


#: the one call through which :func:`atomic_write_bytes` hands bytes to the disk (``os.write``)
_raw_write = os.write


def _write_all(fd: int, data: bytes) -> None:
    view = memoryview(data)
    while view:
        n = _raw_write(fd, view[:_CHUNK])
        if n <= 0:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        view = view[n:]


def atomic_write_bytes(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` through :func:`atomic_path`: ``path`` holds the old content or the
    whole new one, never a part. Raises :class:`OutputError` (one line naming ``path``)."""
    path = Path(path)
    with atomic_path(path) as tmp:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        try:
            _write_all(fd, data)
        finally:
            os.close(fd)
    return path


def atomic_write_text(path: str | Path, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` through :func:`atomic_write_bytes`."""
    return atomic_write_bytes(path, text.encode("utf-8"))


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


def strict_json(data: object, **kwargs) -> str:
    """``json.dumps(data)`` that never writes ``NaN`` / ``Infinity`` (not JSON: strict parsers refuse
    the whole file): a non-finite number becomes ``null``; NumPy scalars and arrays become numbers
    and lists."""
    return json.dumps(_finite(data), allow_nan=False, **kwargs)


def _finite(obj: object) -> object:
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite(v) for v in obj]
    if type(obj).__module__ == "numpy" and hasattr(obj, "tolist"):
        return _finite(obj.tolist())
    return obj


def same_path(a: str | Path, b: str | Path) -> bool:
    """Whether ``a`` and ``b`` name the same file or folder: :func:`os.path.samefile` when both exist
    (symbolic and hard links, bind mounts), else their resolved real paths compared."""
    with contextlib.suppress(OSError, ValueError):
        if os.path.exists(a) and os.path.exists(b):
            return os.path.samefile(a, b)
    return os.path.realpath(a) == os.path.realpath(b)


def lies_inside(path: str | Path, folder: str | Path) -> bool:
    """Whether ``path`` (resolved) lies somewhere below ``folder`` (resolved)."""
    return Path(os.path.realpath(folder)) in Path(os.path.realpath(path)).parents


def refuse_inputs(output: str | Path, inputs: Iterable[str | Path | None], what: str = "output") -> None:
    """Raise :class:`OutputError` when ``output`` is one of ``inputs`` (None entries are skipped):
    no command writes over a file it reads."""
    for src in inputs:
        if src is not None and str(src) and same_path(output, src):
            raise OutputError(f"{output}: is an input of this command ({src}); writing the {what} there would "
                              "destroy it, choose another path")


def check_output_file(path: str | Path, what: str = "output file") -> Path:
    """``path`` as a file to write: not an existing folder, and its folder exists or can be made."""
    path = Path(path)
    try:
        if path.is_dir():
            raise OutputError(f"{path}: is a folder; give a file name for the {what}")
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:  # a name too long, a read-only file system, a file on the way
        raise OutputError(describe_os_error(exc, path)) from None
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
            with contextlib.suppress(OSError):
                (self.path / OWNER_NAME).unlink()
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
        if same_path(path, src):
            raise OutputError(f"{path}: is the input; choose a separate output folder")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(describe_os_error(exc, path)) from None
    if any(p.suffix.lower() in IMAGE_SUFFIXES and p.name not in RUN_OUTPUTS for p in path.iterdir() if p.is_file()):
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
        who = lock_owner(path) or "or a command is reading its map"
        raise OutputError(f"{path}: another vslam run is writing into this folder ({who}); wait for it or choose "
                          "another output folder") from None
    except OSError as exc:
        raise OutputError(describe_os_error(exc, path)) from None
    with contextlib.suppress(OSError):  # best effort: only says who holds the lock
        (path / OWNER_NAME).write_text(json.dumps({"command": _command_line(), "pid": os.getpid(),
                                                    "since": time.strftime("%Y-%m-%d %H:%M:%S")}))
    try:
        previous = _move_previous(path)
    except OSError as exc:
        RunDir(path, lock, None).release()
        raise OutputError(describe_os_error(exc, path)) from None
    return RunDir(path, lock, previous)


def _command_line() -> str:
    """This process's command line as a user typed it (``vslam run ... -o M``), for :data:`OWNER_NAME`."""
    argv = list(sys.argv) or ["?"]
    prog = Path(argv[0]).name
    words = ["vslam", *argv[1:]] if prog in ("vslam", "__main__.py", "-c", "-m") else argv
    return " ".join(shlex.quote(str(w)) for w in words)[:300]


def lock_owner(folder: str | Path) -> str:
    """```vslam run ...`, pid N, since T``: who holds ``folder``'s lock, from :data:`OWNER_NAME`; ""
    when it does not say (a reader, or an older vslam)."""
    try:
        owner = json.loads((Path(folder) / OWNER_NAME).read_text(encoding="utf-8"))
        return f"`{owner['command']}`, pid {int(owner['pid'])}, since {owner['since']}"
    except (OSError, ValueError, KeyError, TypeError):
        return ""


def _open_lock(folder: Path):
    """``(fcntl, fd)`` of ``folder``'s lock file opened for reading, or None (no lock file: no run
    ever wrote here; no ``flock`` on this system)."""
    try:
        import fcntl
    except ImportError:  # Windows
        return None
    try:
        return fcntl, os.open(folder / LOCK_NAME, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_NOFOLLOW", 0))
    except OSError:
        return None


def _try_shared(fcntl, fd: int) -> bool:
    """One non-blocking shared ``flock`` of ``fd``: False while a writer holds the lock."""
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except OSError as exc:
        return exc.errno not in (errno.EAGAIN, errno.EWOULDBLOCK, errno.EACCES)  # else: no locks here
    return True


def _busy(folder: Path, what: str) -> OutputError:
    who = lock_owner(folder) or "another vslam command"
    return OutputError(f"{folder}: {what} is being written by another command ({who}); wait for it to finish, "
                       "then rerun")


@contextlib.contextmanager
def reading_run_dir(folder: str | Path, what: str = "the map") -> Iterator[None]:
    """Hold a shared lock on the run folder ``folder`` while reading it (so no run starts writing it
    meanwhile). When a command is writing it (``vslam run --map M -o M``), say so in one warning line
    and wait up to :data:`READ_WAIT_S` seconds; then :class:`OutputError` naming that command. A
    folder that was never locked, or a file system without locks, is read as it is."""
    folder = Path(folder)
    opened = _open_lock(folder)
    if opened is None:
        yield
        return
    fcntl, fd = opened
    try:
        deadline = None
        while not _try_shared(fcntl, fd):
            if deadline is None:
                deadline = time.monotonic() + READ_WAIT_S
                log.warning("%s: %s is being written by %s; waiting up to %g s for it to finish", folder, what,
                            lock_owner(folder) or "another vslam command", READ_WAIT_S)
            if time.monotonic() >= deadline:
                raise _busy(folder, what)
            time.sleep(0.1)
        yield
    finally:
        os.close(fd)  # releases the shared lock


def refuse_if_written(folder: str | Path, what: str = "the map") -> None:
    """:class:`OutputError` naming the command writing ``folder`` now, if one is (after reading it
    failed: a run that started meanwhile moved its map aside)."""
    folder = Path(folder)
    opened = _open_lock(folder)
    if opened is None:
        return
    fcntl, fd = opened
    try:
        if not _try_shared(fcntl, fd):
            raise _busy(folder, what)
    finally:
        os.close(fd)


def last_complete_run(folder: str | Path) -> tuple[Path, str | None]:
    """``(folder, None)``, or ``(folder/.previous-run, why)`` when the last run into ``folder`` did not
    complete (``why``: its ``stats.json`` error, or "no stats.json") and ``.previous-run/`` keeps a
    complete one (as a stopped ``vslam run --map M -o M`` leaves ``M``)."""
    folder = Path(folder)
    prev = folder / PREVIOUS_NAME
    if not prev.is_dir() or run_complete(folder) or not run_complete(prev):
        return folder, None
    try:
        stats = json.loads((folder / "stats.json").read_text(encoding="utf-8"))
        why = f"stats.json: {stats['error']}" if isinstance(stats, dict) and stats.get("error") else "no stats.json"
    except (OSError, ValueError):
        why = "no stats.json"
    return prev, why


def run_complete(folder: str | Path) -> bool:
    """Whether ``folder`` holds the outputs of a run that completed: a ``stats.json`` (the last file
    a run writes) that is a mapping without an ``error``."""
    try:
        stats = json.loads((Path(folder) / "stats.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return isinstance(stats, dict) and not stats.get("error")


def _move_previous(path: Path) -> Path | None:
    """Clear ``path`` of a previous run's outputs; returns ``.previous-run`` when it exists after.

    ``.previous-run/`` holds the last COMPLETE run: outputs of a run that completed replace it; those
    of a run that failed or was stopped replace it only when it holds no complete run either, and
    are dropped otherwise (so a stopped rerun, then a failed one, never cost the last good results).
    """
    prev = path / PREVIOUS_NAME
    old = [path / n for n in RUN_OUTPUTS if (path / n).exists() or (path / n).is_symlink()]
    if not old:
        return prev if prev.is_dir() else None
    if prev.is_dir() and not run_complete(path) and run_complete(prev):
        for p in old:
            if p.is_dir() and not p.is_symlink():
                shutil.rmtree(p)
            else:
                p.unlink()
        log.warning("%s: the outputs of the last run, which did not complete, were removed; %s keeps the "
                    "last complete run", path, prev)
        return prev
    tag = uuid.uuid4().hex[:8]
    staging = path / f"{PREVIOUS_NAME}.new-{tag}"
    staging.mkdir()
    for p in old:
        os.replace(p, staging / p.name)
    if prev.exists() or prev.is_symlink():
        stale = path / f"{PREVIOUS_NAME}.old-{tag}"
        os.replace(prev, stale)
        os.replace(staging, prev)
        shutil.rmtree(stale, ignore_errors=True)
    else:
        os.replace(staging, prev)
    log.info("%s: the previous run's outputs were moved to %s", path, prev)
    return prev
