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
"""
from __future__ import annotations

import importlib
import logging
import time
from typing import Any, Protocol, runtime_checkable

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


def warm_kernels(modules: tuple[str, ...] = KERNEL_MODULES) -> float:
    """Import ``modules`` and call each one's ``warm()``; returns the milliseconds it took. A module
    that fails to warm is logged and skipped (its kernels then load at their first real call).

    In this thread, not a background one: measured on the 9-frame fr1 desk run, the 0.15 s it
    takes alone became 0.6-1.3 s in a thread beside the System's construction and the first
    frames (the two threads compete for the GIL) and slowed those frames down."""
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
