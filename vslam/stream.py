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
"""
from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import numpy as np

from vslam.trajectory import Trajectory


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
