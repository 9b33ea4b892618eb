"""Recording a few synthetic frames to an .rrd file with the rerun viewer (no display needed)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from vslam.datasets.frame import Frame
from vslam.errors import VslamError
from vslam.geometry.camera import PinholeCamera


@dataclass
class FakeResult:
    T_world_cam: np.ndarray | None
    state: str
    is_keyframe: bool
    n_inliers: int


class FakeSystem:
    def __init__(self) -> None:
        self.calls = 0

    def map_points_xyz(self) -> np.ndarray:
        self.calls += 1
        return np.random.default_rng(0).normal(size=(100, 3))

    def keypoints(self) -> np.ndarray:
        return np.array([[10.0, 12.0], [30.0, 20.0]])


def frames(n: int = 5):
    rng = np.random.default_rng(1)
    cam = PinholeCamera(fx=60.0, fy=60.0, cx=32.0, cy=24.0, width=64, height=48)
    for i in range(n):
        T = np.eye(4)
        T[0, 3] = 0.1 * i
        image = rng.integers(0, 256, (48, 64, 3), dtype=np.uint8) if i % 2 else rng.integers(0, 256, (48, 64), dtype=np.uint8)
        yield Frame(index=i, timestamp=i / 30.0, image=image, camera=cam,
                    depth=np.full((48, 64), 2.0, np.float32), T_world_cam=T)


@pytest.fixture
def rerun_env(monkeypatch):
    pytest.importorskip("rerun", reason="rerun-sdk not installed (pip install 'vslam[viz]'); CI installs it")
    for var, value in (("RERUN_TELEMETRY", "0"), ("TELEMETRY_ENABLED", "false"), ("RERUN_ANALYTICS", "0")):
        monkeypatch.setenv(var, value)


def test_recording_to_rrd(tmp_path, rerun_env):
    from vslam.viz.rerun_viewer import RerunViewer

    path = tmp_path / "rec" / "run.rrd"
    system = FakeSystem()
    viewer = RerunViewer.from_spec(f"rerun:{path}", system=system, map_every=2)
    on_frame = viewer.bind(system)
    for f in frames(5):
        lost = f.index == 3
        on_frame(f, FakeResult(None if lost else f.T_world_cam, "lost" if lost else "ok", f.index == 0, 50 + f.index))
    viewer.close()
    assert len(viewer.positions) == 4  # the lost frame has no pose
    np.testing.assert_allclose(np.asarray(viewer.positions)[:, 0], [0.0, 0.1, 0.2, 0.4])
    assert system.calls >= 3  # frames 0 (keyframe), 1 (every 2nd), 3, 5 ... and at close
    data = path.read_bytes()
    assert len(data) > 20_000  # 5 images of 64x48 and more
    assert data[:4] == b"RRF2"
    for entity in (b"world/camera/image", b"world/trajectory", b"world/map_points", b"keypoints"):
        assert entity in data


def test_bad_viz_specs(rerun_env, tmp_path):
    from vslam.viz.rerun_viewer import RerunViewer

    with pytest.raises(VslamError, match="use rerun, rerun:FILE.rrd"):
        RerunViewer.from_spec("rerunx")
    with pytest.raises(VslamError, match="must end in .rrd"):
        RerunViewer.from_spec(f"rerun:{tmp_path / 'x.txt'}")


def test_map_points_from_the_real_map_store():
    """Without ``map_points_xyz`` the viewer reads the live points of ``system.map.points``."""
    from vslam.viz.rerun_viewer import map_points_of

    class Store:
        position = np.arange(12, dtype=float).reshape(4, 3)
        alive = np.array([True, False, True, True])

        def __len__(self):
            return 3

    class Sys:
        class map:  # noqa: N801
            points = Store()

    np.testing.assert_array_equal(map_points_of(Sys()), [[0, 1, 2], [6, 7, 8]])
    assert map_points_of(None) is None


def _record(path, n: int = 12, **options) -> "object":
    from vslam.viz.rerun_viewer import RerunViewer

    rng = np.random.default_rng(2)
    cam = PinholeCamera(fx=150.0, fy=150.0, cx=79.5, cy=59.5, width=160, height=120)
    viewer = RerunViewer.from_spec(f"rerun:{path}", system=FakeSystem(), **options)
    for i in range(n):
        T = np.eye(4)
        T[0, 3] = 0.1 * i
        frame = Frame(index=i, timestamp=i / 30.0, camera=cam, T_world_cam=T,
                      image=cv2_blur(rng.integers(0, 256, (120, 160, 3), dtype=np.uint8)))
        viewer.on_frame(frame, FakeResult(T, "ok", False, 80))
    viewer.close()
    return viewer


def cv2_blur(image):
    import cv2

    return cv2.GaussianBlur(image, (3, 3), 0.8)


def test_smaller_recordings_with_scale_and_every(tmp_path, rerun_env):
    """--viz-scale 0.5 --viz-every 3: 4 of 12 images, at a quarter of the pixels; every pose kept.
    Measured: 146 kB -> 51 kB (0.35), the images JPEG-compressed in both."""
    full = _record(tmp_path / "full.rrd")
    small = _record(tmp_path / "small.rrd", image_scale=2.0, image_every=3)
    assert full.images_logged == 12 and small.images_logged == 4
    assert len(small.positions) == len(full.positions) == 12
    size_full, size_small = (tmp_path / "full.rrd").stat().st_size, (tmp_path / "small.rrd").stat().st_size
    assert size_small < 0.45 * size_full  # the rest: trajectory, map points, scalars
    assert b"world/camera/image" in (tmp_path / "small.rrd").read_bytes()
    with pytest.raises(VslamError, match="shrunk"):
        _record(tmp_path / "x.rrd", image_scale=0.5)
    with pytest.raises(VslamError, match="viz-every"):
        _record(tmp_path / "x.rrd", image_every=0)


def test_spawn_finds_rerun_beside_python_without_activation(tmp_path, rerun_env, monkeypatch):
    """An unactivated venv: rerun is not on PATH but in the same bin/ as sys.executable."""
    import sys

    import rerun as rr

    from vslam.viz import rerun_viewer

    bindir = tmp_path / "venv" / "bin"
    bindir.mkdir(parents=True)
    exe = bindir / "rerun"
    exe.write_text("#!/bin/sh\n")
    exe.chmod(0o755)
    monkeypatch.setattr(sys, "executable", str(bindir / "python"))
    monkeypatch.setenv("PATH", str(tmp_path / "empty"))
    monkeypatch.setenv("DISPLAY", ":99")  # a desktop (the headless case: test_headless_*)
    assert rerun_viewer.rerun_executable() == str(exe)
    spawned = []
    monkeypatch.setattr(rr, "spawn", lambda **kw: spawned.append(kw))
    viewer = rerun_viewer.RerunViewer.from_spec("rerun")
    assert spawned[0]["executable_path"] == str(exe) and spawned[0]["recording"] is viewer.rec
    viewer.rec.disconnect()
    exe.unlink()
    with pytest.raises(VslamError, match="not found"):
        rerun_viewer.RerunViewer.from_spec("rerun")
