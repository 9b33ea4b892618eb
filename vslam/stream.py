"""The stream protocol: what one run loop (:func:`vslam.runner.run_sequence`) drives.

A *frame tracker* takes frames one by one and poses each of them (or says it could not):

* ``track(frame) -> result``: the result has ``T_world_cam`` (4x4, or None when the frame got no
  pose), ``state`` (``"lost"`` counts as lost; other states are the tracker's own:
  ``ok``/``initializing`` for SLAM, ``tracking``/``localized`` for localization),
  ``is_keyframe`` and ``n_inliers``;
* ``finish()``: end of input (pending optimization runs here);
* ``trajectory()``: the final poses of the posed frames (SLAM re-expresses them through the
  optimized keyframes, localization returns them as tracked);
* ``stats()``: the tracker's counts and per-stage times, merged into ``stats.json`` (they
  override the run loop's own counts of the same name).

Both :class:`vslam.system.System` (SLAM) and :class:`vslam.localizer.Localizer` (localization in
a fixed map) satisfy it. Optional hooks the run loop uses when a tracker has them:

* ``keyframe_trajectory()`` -> ``keyframes.txt``;
* ``save_map_outputs(directory, metadata=..., progress=...)`` -> the map outputs, returning their summary
  (``progress``: a tqdm-like bar advanced once per file);
* ``prepare(frame)`` (called in the decoding thread ahead of ``track``), ``frame_preparer()`` and
  ``adopt_prepared(frame, result, seconds)`` (the same work in a decoding process), see
  :func:`vslam.datasets.prefetch.prefetch` / :func:`~vslam.datasets.prefetch.prefetch_process`.

Compiled kernels: the first call of a cached numba kernel in a process loads its machine code
(~0.15 s for :mod:`vslam.backend.schur_kernels`), which would land in the first local BA. A tracker
calls :func:`warm_kernels` when it is built: every module of :data:`KERNEL_MODULES` gets its
``warm()`` called (each kernel once on tiny inputs), and the time that took is reported as
``stats.json`` ``startup_ms.kernels`` (start-up work, like the imports, before the run's clock).
The first run after an install compiles them instead (~30 s): :func:`kernels_cold` tells so from
numba's cache files, and :func:`compile_notice` lets the CLI say it before it happens.
"""
from __future__ import annotations

import importlib
import importlib.util
import logging
import os
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Callable, Iterator, Protocol, runtime_checkable

import numpy as np

from vslam.trajectory import Trajectory

log = logging.getLogger(__name__)

# Modules of compiled kernels, each with ``warm()``: add a new kernel module here.
KERNEL_MODULES: tuple[str, ...] = (
    "vslam.backend.schur_kernels",
    "vslam.backend.local_problem_kernels",
    "vslam.backend.fuse_kernels",
    "vslam.map.matching_kernels",
    "vslam.map.fusion_kernels",
    "vslam.map.map_kernels",
    "vslam.map.database_kernels",
    "vslam.geometry.pnp_kernels",
    "vslam.features.orb_kernels",
    "vslam.features.orb_describe_kernels",
    "vslam.datasets.depth_kernels",
    "vslam.datasets.png_kernels",
    "vslam.features.match_kernels",
    "vslam.features.stereo_kernels",
    "vslam.loop.vocabulary_kernels",
    "vslam.features.stereo_search_kernels",
)


@runtime_checkable
class FrameResult(Protocol):
    """What ``track`` returns for one frame."""

    T_world_cam: np.ndarray | None
    state: str
    is_keyframe: bool
    n_inliers: int


@runtime_checkable
class FrameTracker(Protocol):
    """A streaming tracker the run loop drives (see the module docstring)."""

    def track(self, frame: Any) -> FrameResult: ...

    def finish(self) -> None: ...

    def trajectory(self) -> Trajectory: ...

    def stats(self) -> dict: ...


#: called (no arguments) just before :func:`warm_kernels` compiles: see :func:`compile_notice`
_compile_listeners: list[Callable[[], None]] = []


@contextmanager
def compile_notice(callback: Callable[[], None]) -> Iterator[None]:
    """Inside the block, ``callback()`` runs once before kernels are warmed from a cold cache
    (:func:`kernels_cold`: a fresh install, ~30 s of compiling): the CLI prints its line there,
    when a tracker is about to be built, after the inputs were checked."""
    _compile_listeners.append(callback)
    try:
        yield
    finally:
        if callback in _compile_listeners:
            _compile_listeners.remove(callback)


def kernels_cold(modules: tuple[str, ...] = KERNEL_MODULES) -> bool:
    """True when some module of ``modules`` has no fresh numba cache, so that warming it compiles
    (~30 s for all of them on a fresh install). Cheap (no numba or kernel import, a few small
    files read): a module counts as cached when one of its ``<module>.*.nbi`` cache indexes, in
    the directories numba's cache locators use (``$NUMBA_CACHE_DIR``, else ``__pycache__`` beside
    the source and the user-wide cache), is of the installed numba and holds the source's hash
    (numba's staleness test)."""
    try:
        from importlib.metadata import version

        numba_version = version("numba")
    except Exception:  # noqa: BLE001 - no numba metadata: nothing to say
        return False
    return any(not _cached(source, numba_version) for source in map(_module_source, modules) if source is not None)


def _module_source(name: str) -> Path | None:
    """The source file of module ``name`` without importing it (nor, for ``vslam.*``, its package)."""
    if name.startswith("vslam."):
        path = Path(__file__).parent.joinpath(*name.split(".")[1:]).with_suffix(".py")  # as numba sees it
        return path if path.is_file() else None
    try:
        spec = importlib.util.find_spec(name)
    except (ImportError, ValueError):
        return None
    return Path(spec.origin) if spec is not None and spec.origin and spec.origin.endswith(".py") else None


def _cache_dirs(source: Path) -> list[Path]:
    """Where numba caches the functions of ``source`` (``numba.core.caching``'s locators)."""
    import hashlib

    sub = f"{source.parent.name}_{hashlib.sha1(str(source.parent).encode()).hexdigest()}"
    if os.environ.get("NUMBA_CACHE_DIR"):
        return [Path(os.environ["NUMBA_CACHE_DIR"]) / sub]
    user = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "numba"
    return [source.parent / "__pycache__", user / sub]


def _cached(source: Path, numba_version: str) -> bool:
    """Whether a cache index of ``source``'s kernels is fresh (see :func:`kernels_cold`)."""
    import hashlib
    import pickle
    import sys

    digest = hashlib.sha256(source.read_bytes()).digest()
    tag = f"py{sys.version_info[0]}{sys.version_info[1]}{getattr(sys, 'abiflags', '')}.nbi"
    for folder in _cache_dirs(source):
        for index in folder.glob(f"{source.stem}.*.{tag}") if folder.is_dir() else ():
            try:
                with open(index, "rb") as f:
                    if pickle.load(f) == numba_version and digest in f.read():
                        return True
            except Exception:  # noqa: BLE001 - an unreadable index is no cache
                continue
    return False


def warm_kernels(modules: tuple[str, ...] = KERNEL_MODULES) -> float:
    """Import ``modules`` and call each one's ``warm()``; returns the milliseconds it took. A module
    that fails to warm is logged and skipped (its kernels then load at their first real call).

    In this thread, not a background one: measured on the 9-frame fr1 desk run, the 0.15 s it
    takes alone became 0.6-1.3 s in a thread beside the System's construction and the first
    frames (the two threads compete for the GIL) and slowed those frames down."""
    if _compile_listeners and kernels_cold(modules):
        for callback in list(_compile_listeners):
            callback()
        _compile_listeners.clear()  # once per process: the next tracker finds them compiled
    t0 = time.perf_counter()
    announced = False
    for name in modules:
        try:
            importlib.import_module(name).warm()
        except Exception:  # never fail a run over a start-up optimization
            log.warning("warming the kernels of %s failed", name, exc_info=True)
        if not announced and time.perf_counter() - t0 > 1.0:  # numba is compiling: a fresh install
            log.info("first run: compiling the numeric kernels (10-20 s, once; cached for the next runs)")
            announced = True
    seconds = time.perf_counter() - t0
    return round(1000.0 * seconds, 1)
