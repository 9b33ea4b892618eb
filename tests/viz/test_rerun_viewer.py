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
