"""`vslam run` outputs: trajectory flushed per frame, stats, config, sparse map, topology, saved map."""
from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np
import pytest

from vslam.api import run_path
from vslam.datasets.synthetic import SyntheticConfig, distance_to_scene, render_sequence
from vslam.eval import evaluate_trajectories
from vslam.trajectory import read_tum
from vslam.reconstruction import read_ply, read_topology
from vslam.runner import run_sequence


@dataclass
class _Result:
    T_world_cam: np.ndarray | None
    state: str


class _CrashingSystem:
    """Tracks frames 0..4 with known poses, then raises (a crash mid-run)."""

    def __init__(self):
        self.n = 0

    def track(self, frame):
        if self.n == 5:
            raise RuntimeError("boom")
        self.n += 1
        T = np.eye(4)
        T[0, 3] = frame.timestamp
        return _Result(T, "ok")

    def finish(self):  # pragma: no cover - never reached
        pass

    def stats(self):
        return {"keyframes": 1, "map_points": 0}


@dataclass
class _Frame:
    index: int
    timestamp: float


def test_a_crash_keeps_the_poses_tracked_so_far(tmp_path):
    frames = [_Frame(i, 0.1 * i) for i in range(10)]
    with pytest.raises(RuntimeError, match="boom"):
        run_sequence(_CrashingSystem(), frames, output_dir=tmp_path, progress=False)
    traj = read_tum(tmp_path / "trajectory.txt")
    assert len(traj) == 5
    np.testing.assert_allclose(traj.positions[:, 0], [0.0, 0.1, 0.2, 0.3, 0.4], atol=1e-9)
    stats = json.loads((tmp_path / "stats.json").read_text())
    assert stats["frames"] == 5 and stats["tracked"] == 5
    assert "boom" in stats["error"]


@pytest.fixture(scope="module")
def synthetic_run(tmp_path_factory):
    root = tmp_path_factory.mktemp("seq")
    seq = render_sequence(root / "seq", SyntheticConfig(n_frames=40, width=320, height=240, fx=262.5, fy=262.5,
                                                         cx=159.5, cy=119.5, stereo=False, seed=3))
    out = root / "run"
    result = run_path(seq, out, sensor="rgbd", dense=True)
    return seq, out, result


def test_run_writes_every_output_and_tracks_accurately(synthetic_run):
    seq, out, result = synthetic_run
    stats = json.loads((out / "stats.json").read_text())
    for key in ("frames", "tracked", "lost", "keyframes", "map_points", "loops", "wall_s", "fps", "stage_ms"):
        assert key in stats
    assert stats["frames"] == 40 and stats["tracked"] == 40 and stats["lost"] == 0
    assert stats["ate_rmse"] < 0.02
    # RGB-D has metric depth: the published ATE is SE(3)-aligned (a Sim(3) alignment would absorb
    # part of the error into a scale and report a smaller figure)
    gt = read_tum(seq / "groundtruth.txt")
    assert stats["scale"] == 1.0
    assert stats["ate_rmse"] == pytest.approx(evaluate_trajectories(result.trajectory, gt, align="se3").ate.rmse,
                                              rel=1e-12)
    assert stats["ate_rmse"] > evaluate_trajectories(result.trajectory, gt, align="sim3").ate.rmse
    # resident memory sampled at the start and every 100 frames (40 frames: the start only)
    assert stats["rss_mb"][0][0] == 0 and stats["rss_mb"][0][1] > 50 and len(stats["rss_mb"]) == 1
    assert (out / "config.yaml").is_file()
    traj = read_tum(out / "trajectory.txt")
    assert len(traj) == 40
    kf = read_tum(out / "keyframes.txt")
    assert len(kf) == stats["keyframes"]


def test_sparse_map_topology_and_saved_map(synthetic_run):
    from vslam.map.io import load_map

    seq, out, result = synthetic_run
    stats = json.loads((out / "stats.json").read_text())
    ev = evaluate_trajectories(result.trajectory, read_tum(seq / "groundtruth.txt"), align="se3")
    ply = read_ply(out / "sparse.ply")
    assert len(ply.points) == stats["map_points"]
    assert ply.colors is not None and ply.colors.any(axis=1).mean() > 0.95  # coloured from the images
    # map points lie on the true surfaces of the room (after the trajectory's SE(3) alignment)
    X_gt = ply.points @ ev.alignment.R.T + ev.alignment.t
    d = distance_to_scene(X_gt)
    assert np.median(d) < 0.025 and np.mean(d < 0.05) > 0.7
    nodes, edges = read_topology(out / "topology.json")
    assert len(nodes) == stats["keyframes"]
    kinds = {e["kind"] for e in edges}
    assert {"odometry", "covisibility"} <= kinds
    slam_map, db, cam, meta = load_map(out)
    assert slam_map.n_keyframes == stats["keyframes"] and slam_map.n_points == stats["map_points"]
    assert cam.fx == pytest.approx(262.5)
    # the dense mesh of the room
    mesh = read_ply(out / "mesh.ply")
    assert len(mesh.points) > 5000 and mesh.faces is not None and len(mesh.faces) > 5000


def test_background_decoding_and_detection_change_nothing(shared_data):
    """Decoding and feature detection ahead in the prefetch thread give exactly the poses of the
    sequential run (detection needs no tracking state), and the tracker did not detect itself."""
    from vslam.config import Config, load_config
    from vslam.datasets import open_dataset
    from vslam.system import System

    ds = open_dataset(shared_data / "7scenes_redkitchen", sensor="rgbd")
    cfg = load_config(Config, None, ["backend.local_ba=false", "loop.enabled=false"])
    runs = []
    for depth in (0, 3):
        system = System(cfg, ds.camera, sensor="rgbd")
        runs.append(run_sequence(system, ds.frames(0, 25), progress=False, prefetch_depth=depth))
    seq, pre = runs
    assert seq.stats["tracked"] == pre.stats["tracked"] == 25
    np.testing.assert_array_equal(seq.trajectory.T_world_cam, pre.trajectory.T_world_cam)
    # sequential: detection is tracking time; prefetched: the frames decoded while the tracker
    # was busy (most of them: tracking is slower than decoding) were detected on the other thread
    assert seq.stats["stage_ms"]["prepare"] == 0.0 and seq.stats["stage_ms"]["features"] > 2.0
    assert pre.stats["stage_ms"]["prepare"] > 0.0
    assert "read_ms" in pre.stats


class _ThreadProbe:
    """Records OpenCV's thread count and the thread each frame was prepared in."""

    def __init__(self):
        self.cv_threads, self.prepared_in = [], {}

    def prepare(self, frame):
        import threading

        self.prepared_in[frame.index] = threading.current_thread().name

    def track(self, frame):
        import time

        import cv2

        self.cv_threads.append(cv2.getNumThreads())
        time.sleep(0.03)  # a tracker slower than decoding: the prefetch thread gets ahead
        return _Result(np.eye(4), "ok")

    def finish(self):
        pass

    def stats(self):
        return {}

    def trajectory(self):
        from vslam.trajectory import Trajectory

        return Trajectory(np.zeros(0), np.zeros((0, 4, 4)))

    def keyframe_trajectory(self):
        return self.trajectory()


def test_opencv_threads_set_for_the_run_and_restored():
    import cv2

    before = cv2.getNumThreads()
    probe = _ThreadProbe()
    frames = [_Frame(i, 0.1 * i) for i in range(6)]
    res = run_sequence(probe, frames, progress=False, cv_threads=1, prefetch_depth=2)
    assert res.stats["frames"] == 6 and probe.cv_threads == [1] * 6
    assert cv2.getNumThreads() == before
    # frames decoded while the tracker was busy are prepared ahead (the first ones go straight
    # to the idle tracker, which then does that work itself)
    assert len(probe.prepared_in) >= 3 and set(probe.prepared_in.values()) == {"vslam-prefetch"}
    probe = _ThreadProbe()
    run_sequence(probe, frames, progress=False, cv_threads=None, prefetch_depth=0)
    assert probe.cv_threads == [before] * 6 and probe.prepared_in == {}  # no prefetch: prepare is the tracker's job
