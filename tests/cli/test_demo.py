"""``vslam demo``: renders the synthetic sequence and plots its ground truth."""
from __future__ import annotations

import numpy as np

from vslam.cli import main
from vslam.eval.trajectory import read_tum


def test_demo_writes_sequence_and_plot(tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["demo", "--output", str(out), "--frames", "3", "--no-progress"]) == 0
    seq = out / "sequence"
    assert (out / "ground_truth.png").stat().st_size > 10_000
    for name in ("rgb.txt", "depth.txt", "right.txt", "groundtruth.txt", "camera.yaml"):
        assert (seq / name).is_file()
    assert len(list((seq / "rgb").glob("*.png"))) == 3
    gt = read_tum(seq / "groundtruth.txt")
    # a 3-frame loop: start, half-way round, back at the start
    assert np.linalg.norm(gt.positions[0] - gt.positions[2]) < 1e-6
    assert np.linalg.norm(gt.positions[0] - gt.positions[1]) > 2.0
    text = capsys.readouterr().out
    assert str(seq) in text and "ground_truth.png" in text


def test_demo_drift_not_available(tmp_path, capsys):
    assert main(["demo", "drift", "--output", str(tmp_path / "d")]) == 2
    assert "not available yet" in capsys.readouterr().err
    assert not (tmp_path / "d").exists()
