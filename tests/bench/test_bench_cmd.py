"""`vslam bench` on the command line (dry run: synthetic run folders, no SLAM)."""
from __future__ import annotations

import json

from vslam.cli import main


def test_bench_dry_run_writes_results_and_reports_progress(tmp_path, capsys):
    spec = tmp_path / "spec.yaml"
    spec.write_text("repeats: 2\nruns:\n  - {name: r1, data: somewhere, set: {fake.fps: 20}}\n"
                    "  - {name: r2, data: somewhere, repeats: 1, set: {fake.fail: true}}\n")
    (tmp_path / "somewhere").mkdir()  # the dry run checks the data paths as the real run does
    out = tmp_path / "out"
    rc = main(["bench", str(spec), "--output", str(out), "--dry-run", "--workers", "0",
               "--no-plots"])
    text = capsys.readouterr().out
    assert rc == 1  # one run failed
    assert "[1/3] r1 #0: 20/20 tracked, ATE 0.0100 m, 20.0 frames/s (2.00x real time)" in text
    assert "r2 #0: FAILED: RuntimeError: fake failure" in text
    assert "| r1 | mono | 2/2 | 20 |" in text
    rows = json.loads((out / "results.json").read_text())["rows"]
    assert len(rows) == 3
    assert not (out / "ate.png").exists() and (out / "runs/r1/1/trajectory.txt").is_file()


def test_bench_cli_errors_are_one_line(tmp_path, capsys, monkeypatch):
    monkeypatch.delenv("PYORBSLAM3_VOCAB", raising=False)
    spec = tmp_path / "spec.yaml"
    spec.write_text("runs:\n  - {name: r1, data: missing_folder}\n")
    assert main(["bench", str(spec), "--output", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "vslam bench: error:" in err and "missing_folder does not exist" in err
    assert main(["bench", str(spec), "--output", str(tmp_path / "o"), "--dry-run"]) == 2  # checked the same way
    assert "missing_folder does not exist" in capsys.readouterr().err
    (tmp_path / "missing_folder").mkdir()
    assert main(["bench", str(spec), "--output", str(tmp_path / "o"), "--dry-run", "--address", "x:1"]) == 2
    assert "--address is for --executor ray" in capsys.readouterr().err
    assert main(["bench", str(spec), "--output", str(tmp_path / "o"), "--dry-run", "--baseline", "orbslam3"]) == 2
    assert "--vocabulary" in capsys.readouterr().err
