"""The stream protocol: the SLAM system and the localizer are both frame trackers, and the run loop
needs nothing else from a tracker (its optional hooks are optional)."""
from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np

from vslam.runner import run_sequence
from vslam.stream import FrameResult, FrameTracker
from vslam.trajectory import Trajectory, read_tum


@dataclass
class _Result:
    T_world_cam: np.ndarray | None
    state: str
    is_keyframe: bool = False
    n_inliers: int = 0


@dataclass
class _Frame:
    index: int
    timestamp: float


class _Minimal:
    """Only the protocol: poses frames with an even index (x = timestamp), loses the others."""

    def __init__(self):
        self.poses: list[tuple[float, np.ndarray]] = []
        self.finished = False

    def track(self, frame):
        if frame.index % 2:
            return _Result(None, "lost")
        T = np.eye(4)
        T[0, 3] = frame.timestamp
        self.poses.append((frame.timestamp, T))
        return _Result(T, "ok")

    def finish(self):
        self.finished = True

    def trajectory(self):
        return Trajectory(np.array([t for t, _ in self.poses]), np.stack([T for _, T in self.poses]))

    def stats(self):
        return {"lost": 99}  # the tracker's counts override the loop's


def test_system_and_localizer_satisfy_the_protocol():
    from vslam.config import Config
    from vslam.geometry.camera import PinholeCamera
    from vslam.localizer import LocalizeResult, Localizer
    from vslam.map.map import Map
    from vslam.system import System, TrackResult

    cam = PinholeCamera(fx=262.5, fy=262.5, cx=159.5, cy=119.5, width=320, height=240)
    system, localizer = System(Config(), cam, sensor="rgbd"), Localizer(Map(), None, cam, sensor="rgbd")
    assert isinstance(system, FrameTracker) and isinstance(localizer, FrameTracker)
    # both loaded the compiled kernels when built (vslam.stream.warm_kernels), and say how long it took
    assert system.stats()["startup_ms"]["kernels"] >= 0.0 and localizer.stats()["startup_ms"]["kernels"] >= 0.0
    assert not isinstance(object(), FrameTracker)
    assert isinstance(TrackResult(0, 0.0, None, "lost", False, 0), FrameResult)
    assert isinstance(LocalizeResult(None, "lost", 0), FrameResult)


def test_the_run_loop_needs_only_the_protocol(tmp_path):
    tracker = _Minimal()
    assert isinstance(tracker, FrameTracker)
    frames = [_Frame(i, 0.5 * i) for i in range(8)]
    res = run_sequence(tracker, frames, total=8, output_dir=tmp_path, progress=False, prefetch_depth=2,
                       extra_stats={"sensor": "test"})
    assert tracker.finished
    traj = read_tum(tmp_path / "trajectory.txt")
    np.testing.assert_allclose(traj.positions[:, 0], [0.0, 1.0, 2.0, 3.0], atol=1e-9)
    np.testing.assert_array_equal(res.trajectory.timestamps, [0.0, 1.0, 2.0, 3.0])
    stats = json.loads((tmp_path / "stats.json").read_text())
    assert (stats["frames"], stats["tracked"], stats["lost"], stats["skipped_frames"]) == (8, 4, 99, 0)
    assert stats["sensor"] == "test" and "error" not in stats
    # no keyframes, no map: none of those outputs
    assert sorted(p.name for p in tmp_path.iterdir() if not p.name.startswith(".")) == ["stats.json", "trajectory.txt"]


def _kernels(module) -> dict:
    """The public numba dispatchers of a kernel module (helpers compiled into them are not called alone)."""
    return {name: f for name, f in vars(module).items() if not name.startswith("_") and hasattr(f, "signatures")}


def test_warm_kernels_loads_every_kernel_with_the_types_the_solver_passes():
    """After warm_kernels every public kernel of every registered module has machine code, and a
    local BA (mono, stereo, RGB-D) needs no other signature, so it loads or compiles nothing."""
    import importlib

    from vslam.backend.bundle_adjustment import local_bundle_adjustment
    from vslam.backend.synthetic import make_ba_problem
    from vslam.stream import KERNEL_MODULES, warm_kernels

    assert warm_kernels() >= 0.0
    modules = [importlib.import_module(name) for name in KERNEL_MODULES]
    before = {(m.__name__, k): len(f.signatures) for m in modules for k, f in _kernels(m).items()}
    assert before and all(n >= 1 for n in before.values()), before
    for sensor in ("mono", "stereo", "rgbd"):
        problem, _ = make_ba_problem(n_keyframes=4, n_points=40, sensor=sensor, seed=2)
        local_bundle_adjustment(problem)
    after = {(m.__name__, k): len(f.signatures) for m in modules for k, f in _kernels(m).items()}
    assert after == before


def test_a_kernel_module_that_fails_to_warm_is_skipped(caplog):
    from vslam.stream import warm_kernels

    ms = warm_kernels(("vslam.no_such_kernels", "vslam.backend.schur_kernels"))
    assert 0.0 <= ms < 60_000.0
    assert "vslam.no_such_kernels" in caplog.text


def test_kernels_cold_follows_numbas_cache(tmp_path, monkeypatch):
    """Cold before a kernel module was ever compiled, warm once numba cached it, cold again when its
    source changes (numba's own staleness test), all without importing the module."""
    import importlib
    import sys

    from vslam.stream import kernels_cold

    name = "tiny_issue25_kernels"
    src = tmp_path / f"{name}.py"
    src.write_text("from numba import njit\n\n\n@njit(cache=True)\ndef add(a, b):\n    return a + b\n\n\n"
                   "def warm():\n    add(1, 2)\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    assert kernels_cold((name,)) and name not in sys.modules
    try:
        assert importlib.import_module(name).add(2, 3) == 5  # compiles, writes the cache
    finally:
        sys.modules.pop(name, None)
    assert not kernels_cold((name,))
    assert kernels_cold((name, "vslam.backend.schur_kernels")) is kernels_cold(("vslam.backend.schur_kernels",))
    src.write_text(src.read_text() + "\n# edited: the cached machine code is stale\n")
    assert kernels_cold((name,))
    assert not kernels_cold(("no_such_module_issue25",))  # nothing to compile


def test_compile_notice_runs_once_before_a_cold_warm(monkeypatch):
    import vslam.stream as stream

    calls = []
    monkeypatch.setattr(stream, "kernels_cold", lambda modules=stream.KERNEL_MODULES: True)
    with stream.compile_notice(lambda: calls.append(1)):
        stream.warm_kernels(("vslam.map.map_kernels",))
        stream.warm_kernels(("vslam.map.map_kernels",))  # a second tracker in the same process
    assert calls == [1]
    monkeypatch.setattr(stream, "kernels_cold", lambda modules=stream.KERNEL_MODULES: False)
    with stream.compile_notice(lambda: calls.append(2)):
        stream.warm_kernels(("vslam.map.map_kernels",))
    stream.warm_kernels(("vslam.map.map_kernels",))  # no listener: nothing is called
    assert calls == [1]
