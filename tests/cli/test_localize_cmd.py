"""``vslam localize``: outputs on a small synthetic map, and clean errors for missing/corrupt maps."""
from __future__ import annotations

import json

import numpy as np
import pytest

from vslam.api import run_path
from vslam.cli import main
from vslam.datasets.synthetic import SyntheticConfig, render_sequence
from vslam.trajectory import read_tum


@pytest.fixture(scope="module")
def small_map(tmp_path_factory):
    root = tmp_path_factory.mktemp("locmap")
    cfg = SyntheticConfig(n_frames=16, laps=0.06, width=320, height=240, fx=262.5, fy=262.5, cx=159.5, cy=119.5,
                          stereo=False, pixel_noise=1.0, seed=5)
    render_sequence(root / "seq", cfg)
    run_path(root / "seq", root / "run", sensor="rgbd", max_frames=12)
    return root / "seq", root / "run"


def test_localize_writes_trajectory_and_stats(small_map, tmp_path, capsys):
    seq, run = small_map
    out = tmp_path / "loc"
    rc = main(["localize", str(run), str(seq), "--start-frame", "8", "--max-frames", "8", "-o", str(out),
               "--no-progress", "--set", "localize.min_inliers=25"])
    assert rc == 0
    text = capsys.readouterr().out
    assert "8/8 frames localized" in text and "ATE RMSE" in text
    stats = json.loads((out / "stats.json").read_text())
    # one set of counts, the same in the summary line and stats.json: localized = tracked + relocalized
    line = text.splitlines()[0]
    assert line.startswith(f"8/8 frames localized (100.0 %: {stats['tracked']} tracked + "
                           f"{stats['relocalizations']} relocalized), 0 lost, ") and str(run.resolve()) in line
    assert stats["frames"] == 8 and stats["localized"] == 8 and stats["lost"] == 0
    assert stats["relocalizations"] >= 1 and stats["tracked"] + stats["relocalizations"] == 8
    assert stats["ate_rmse"] < 0.03 and stats["matched_poses"] == 8
    assert set(stats["stage_ms"]) >= {"features", "relocalize"}
    # the run loop of `vslam run`: frames decoded ahead, skipped frames counted, the map's size
    assert stats["prefetch"] == "thread" and stats["read_ms"] >= 0 and stats["skipped_frames"] == 0
    assert stats["localized_ratio"] == 1.0 and stats["start_frame"] == 8 and stats["map_keyframes"] >= 2
    assert not (out / "keyframes.txt").exists() and not (out / "map").exists()  # the map is not rewritten
    traj = read_tum(out / "trajectory.txt")
    assert len(traj) == 8 and np.all(np.diff(traj.timestamps) > 0)


def test_missing_and_corrupt_map_give_clean_errors(small_map, tmp_path, capsys):
    seq, run = small_map
    rc = main(["localize", str(tmp_path / "nope"), str(seq), "-o", str(tmp_path / "o1")])
    assert rc == 2
    err = capsys.readouterr().err
    assert "nope" in err and "Traceback" not in err
    # a corrupt copy of the map: truncate the points file
    bad = tmp_path / "bad"
    (bad / "map").mkdir(parents=True)
    for f in (run / "map").iterdir():
        (bad / "map" / f.name).write_bytes(f.read_bytes())
    pts = bad / "map" / "points.npz"
    pts.write_bytes(pts.read_bytes()[: pts.stat().st_size // 2])
    rc = main(["localize", str(bad), str(seq), "-o", str(tmp_path / "o2")])
    assert rc == 2
    err = capsys.readouterr().err
    assert "points.npz" in err and "Traceback" not in err
    # a bad override is a config error, also exit 2
    rc = main(["localize", str(run), str(seq), "-o", str(tmp_path / "o3"), "--set", "localize.nope=1"])
    assert rc == 2


def test_interrupted_localize_keeps_the_poses_so_far_and_says_so(small_map, tmp_path, capsys, monkeypatch):
    """``vslam localize`` runs in the run loop of ``vslam run``: a stop (Ctrl-C, SIGTERM) keeps the
    poses streamed so far, whole lines, and writes stats.json with the error."""
    from vslam.localizer import Localizer

    seq, run = small_map
    real = Localizer.track

    def track(self, frame):
        if frame.index == 11:
            raise KeyboardInterrupt
        return real(self, frame)

    monkeypatch.setattr(Localizer, "track", track)
    out = tmp_path / "loc"
    rc = main(["localize", str(run), str(seq), "--start-frame", "8", "--max-frames", "8", "-o", str(out),
               "--no-progress", "--set", "localize.min_inliers=25"])
    err = capsys.readouterr().err
    assert rc == 130 and "interrupted" in err and "Traceback" not in err
    stats = json.loads((out / "stats.json").read_text())
    assert stats["error"] == "interrupted" and stats["frames"] == 3 and stats["localized"] == 3
    assert "ate_rmse" not in stats
    lines = (out / "trajectory.txt").read_text().splitlines()
    assert lines[0].startswith("#") and len(lines) == 4 and all(len(ln.split()) == 8 for ln in lines[1:])


def test_localize_names_its_ground_truth_and_takes_gt(small_map, tmp_path, capsys):
    """stats.json and the summary line name the ground truth; --gt FILE chooses another, --gt none none."""
    from vslam.trajectory import Trajectory, write_tum

    seq, run = small_map
    args = ["localize", str(run), str(seq), "--start-frame", "8", "--max-frames", "4", "--no-progress",
            "--set", "localize.min_inliers=25"]
    assert main(args + ["-o", str(tmp_path / "own")]) == 0
    own = json.loads((tmp_path / "own" / "stats.json").read_text())
    assert own["gt_file"] == str((seq / "groundtruth.txt").resolve()) and own["gt_frame"] == "rgb"
    assert f"ground truth {own['gt_file']}, frame rgb" in capsys.readouterr().out
    gt = read_tum(seq / "groundtruth.txt")
    T = gt.T_world_cam.copy()
    T[:, 0, 3] += np.where(np.arange(len(T)) % 2, 0.2, -0.2)  # +-20 cm across the path
    other = tmp_path / "other.txt"
    write_tum(other, Trajectory(gt.timestamps, T))
    assert main(args + ["-o", str(tmp_path / "other"), "--gt", str(other)]) == 0
    chosen = json.loads((tmp_path / "other" / "stats.json").read_text())
    assert chosen["gt_file"] == str(other) and chosen["gt_frame"] == "as given"
    assert chosen["ate_rmse"] > 0.1 > own["ate_rmse"]
    assert main(args + ["-o", str(tmp_path / "none"), "--gt", "none"]) == 0
    none = json.loads((tmp_path / "none" / "stats.json").read_text())
    assert none["gt_file"] is None and "ate_rmse" not in none
