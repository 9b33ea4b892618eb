"""``vslam demo``: renders the synthetic sequence, runs SLAM on it through the real reader, evaluates."""
from __future__ import annotations

import json

import numpy as np

from vslam.cli import main
from vslam.trajectory import read_tum


def test_slam_demo_tracks_the_synthetic_loop(tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["demo", "--output", str(out), "--frames", "80", "--no-progress"]) == 0
    seq = out / "sequence"
    assert (out / "ground_truth.png").stat().st_size > 10_000
    assert (out / "run" / "trajectory.png").stat().st_size > 10_000
    for name in ("rgb.txt", "depth.txt", "groundtruth.txt", "camera.yaml"):
        assert (seq / name).is_file()
    gt = read_tum(seq / "groundtruth.txt")
    assert len(gt) == 80
    # the path is a closed loop
    assert np.linalg.norm(gt.positions[0] - gt.positions[-1]) < 1e-6
    stats = json.loads((out / "run" / "stats.json").read_text())
    assert stats["tracked"] == 80 and stats["lost"] == 0
    assert stats["ate_rmse"] < 0.03
    text = capsys.readouterr().out
    assert "ATE RMSE" in text and str(seq) in text


def test_drift_demo_loop_closure_removes_drift(tmp_path, capsys):
    from vslam.demo import drift_demo

    res = drift_demo(tmp_path / "api", noise=1.0, seed=0)
    assert res["end_drift_before"] > 1.0
    assert res["end_drift_after"] < res["end_drift_before"] / 5
    assert res["ate_after"] < res["ate_before"] / 5
    out = tmp_path / "drift"
    assert main(["demo", "drift", "--output", str(out)]) == 0
    assert (out / "drift_demo.png").stat().st_size > 10_000
    assert "end-point drift" in capsys.readouterr().out


def test_bad_demo_arguments_exit_cleanly(tmp_path, capsys):
    assert main(["demo", "drift", "--output", str(tmp_path / "d"), "--noise", "-1"]) == 2
    assert "--noise must be > 0" in capsys.readouterr().err
