"""``vslam reconstruct RUN_DIR`` / ``reconstruct_run`` on a run folder over a rendered synthetic sequence."""
from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

pytest.importorskip("open3d")

from vslam.cli import main  # noqa: E402
from vslam.trajectory import Trajectory, write_tum  # noqa: E402
from vslam.reconstruction import read_ply, reconstruct_run, select_frames  # noqa: E402


@pytest.fixture(scope="module")
def sequence(tmp_path_factory, small_config):
    """A 24-frame rgbd + stereo synthetic sequence on disk (TUM layout) and its ground truth."""
    from vslam.datasets.synthetic import SyntheticSequence, render_sequence

    cfg = dataclasses.replace(small_config, n_frames=24)
    root = render_sequence(tmp_path_factory.mktemp("seq") / "synthetic", cfg)
    return root, SyntheticSequence(cfg).ground_truth()


def make_run(folder, seq_root, gt: Trajectory, sensor: str = "rgbd", keyframes=(0, 6, 12, 18)):
    folder.mkdir(parents=True, exist_ok=True)
    stats = {"frames": len(gt), "tracked": len(gt), "sensor": sensor, "dataset": "tum", "path": str(seq_root),
             "start_frame": 0}
    (folder / "stats.json").write_text(json.dumps(stats))
    write_tum(folder / "trajectory.txt", gt)
    write_tum(folder / "keyframes.txt", gt.subset(np.asarray(keyframes)))
    return folder


def test_cli_fuses_the_keyframes(tmp_path, sequence, scene_distance, capsys):
    root, gt = sequence
    run = make_run(tmp_path / "run", root, gt)
    rc = main(["reconstruct", str(run), "--voxel", "0.04", "--max-depth", "4"])
    out = capsys.readouterr().out
    assert rc == 0, out
    assert "fused 4 frames (keyframes.txt" in out and "mesh:" in out and "point cloud:" in out
    mesh, cloud = read_ply(run / "mesh.ply"), read_ply(run / "dense.ply")
    assert mesh.is_mesh and len(mesh.points) > 5000 and len(cloud.points) > 5000
    # depth PNGs (0.2 mm steps) and the estimated (here: exact) keyframe poses: mm-level surfaces
    assert scene_distance(mesh.points).mean() < 0.005


def test_api_every_nth_frame_and_json(tmp_path, sequence, scene_distance):
    root, gt = sequence
    run = make_run(tmp_path / "run", root, gt)
    res = reconstruct_run(run, voxel_size=0.05, every=8, output_dir=tmp_path / "out")
    assert res["frames_fused"] == 3 and res["poses_from"] == "trajectory.txt every 8"
    assert res["voxel_size"] == 0.05 and res["depth_max"] == 4.0 and res["sensor"] == "rgbd"
    assert res["mesh"] == str(tmp_path / "out" / "mesh.ply") and res["vertices"] == len(read_ply(res["mesh"]).points)
    assert not (run / "mesh.ply").exists()
    assert scene_distance(read_ply(res["dense"]).points).mean() < 0.005


def test_stereo_run_uses_sgbm(tmp_path, sequence, scene_distance):
    root, gt = sequence
    run = make_run(tmp_path / "run", root, gt, sensor="stereo", keyframes=(0, 12))
    res = reconstruct_run(run, voxel_size=0.05, max_frames=2)
    # auto range for the 320 px rig: depth of an 8 px disparity = 262.5 * 0.1 / 8
    assert res["depth_max"] == pytest.approx(3.28125) and res["frames_fused"] == 2
    assert scene_distance(read_ply(res["mesh"]).points).mean() < 0.04


def test_errors_are_one_line(tmp_path, sequence, capsys):
    root, gt = sequence
    assert main(["reconstruct", str(tmp_path)]) == 2
    assert "no stats.json" in capsys.readouterr().err
    run = make_run(tmp_path / "mono", root, gt, sensor="mono")
    assert main(["reconstruct", str(run)]) == 2
    assert "needs metric depth" in capsys.readouterr().err
    shifted = Trajectory(gt.timestamps + 100.0, gt.T_world_cam)
    run = make_run(tmp_path / "other", root, shifted)
    assert main(["reconstruct", str(run)]) == 2
    assert "no timestamp of keyframes.txt matches" in capsys.readouterr().err


def test_select_frames_matches_within_tolerance():
    ts = np.array([0.0, 0.1, 0.2, 0.3])
    frames, poses = select_frames(ts, np.array([0.1004, 0.25, 0.3, -1.0]))
    np.testing.assert_array_equal(frames, [1, 3])
    np.testing.assert_array_equal(poses, [0, 2])


class SpyBar:
    """A tqdm-like factory recording what it was asked to show."""

    def __init__(self):
        self.calls, self.items = [], 0

    def __call__(self, iterable=None, **kw):
        self.calls.append(kw)
        for item in iterable:
            self.items += 1
            yield item


def test_fusion_progress_goes_to_the_given_bar_only(tmp_path, sequence, capsys):
    """``progress=`` gets one frame per fused keyframe; without it, and from the CLI when stderr is
    not a terminal (as under pytest), nothing is printed."""
    root, gt = sequence
    run = make_run(tmp_path / "run", root, gt)
    spy = SpyBar()
    res = reconstruct_run(run, voxel_size=0.08, progress=spy)
    assert spy.calls == [{"total": 4, "desc": "TSDF fusion", "unit": "frame"}] and spy.items == res["frames_fused"] == 4
    assert main(["reconstruct", str(run), "--voxel", "0.08"]) == 0
    assert "TSDF" not in capsys.readouterr().err
    from vslam.api import progress_bar

    assert progress_bar(False) is None and progress_bar(True) is None  # stderr is captured, not a TTY
