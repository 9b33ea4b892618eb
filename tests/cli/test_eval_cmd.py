"""``vslam eval``: printed numbers, JSON, plot, KITTI options, and clean errors (no traceback)."""
from __future__ import annotations

import json

import pytest

from vslam.cli import main


@pytest.fixture
def tum(shared_data):
    return shared_data / "trajectories" / "tum"


def test_eval_sim3_json_and_plot(tum, tmp_path, capsys):
    out_json, out_png = tmp_path / "r.json", tmp_path / "r.png"
    rc = main(["eval", str(tum / "freiburg1_xyz-groundtruth.txt"), str(tum / "freiburg1_xyz-ORB_kf_mono.txt"),
               "--align", "sim3", "--json", str(out_json), "--plot", str(out_png)])
    assert rc == 0
    text = capsys.readouterr().out
    assert "matched poses: 32" in text and "scale 1.105622" in text and "ATE (m)" in text
    d = json.loads(out_json.read_text())
    for key in ("ate_rmse", "rpe_trans_rmse", "rpe_rot_deg_rmse", "matched_poses", "scale",
                "ate_mean", "ate_median", "ate_max", "ate_std", "alignment"):
        assert key in d
    assert d["matched_poses"] == 32 and d["alignment"] == "sim3"
    assert d["ate_rmse"] == pytest.approx(0.0097546, abs=1e-6)
    assert out_png.stat().st_size > 20_000


def test_eval_kitti_by_index_with_lengths(shared_data, tmp_path, capsys):
    k = shared_data / "trajectories" / "kitti"
    out_json = tmp_path / "k.json"
    rc = main(["eval", str(k / "KITTI_00_gt.txt"), str(k / "KITTI_00_ORB.txt"), "--kitti",
               "--lengths", "100", "200", "--delta", "10", "--delta-unit", "m", "--json", str(out_json)])
    assert rc == 0
    assert "matched poses: 4541 (by index)" in capsys.readouterr().out
    d = json.loads(out_json.read_text())
    assert d["associated_by"] == "index" and d["kitti"]["lengths"] == [100.0, 200.0]
    assert 0.3 < d["kitti_t_err_percent"] < 1.5 and 0.05 < d["kitti_r_err_deg_per_100m"] < 0.6
    assert d["rpe_delta_unit"] == "m" and d["rpe_pairs"] > 300


def test_eval_fr2_desk_duplicates(tum, capsys, caplog):
    """The official fr2/desk ground truth repeats a timestamp: accepted with a warning (as evo)."""
    args = ["eval", str(tum / "fr2_desk_groundtruth.txt"), str(tum / "fr2_desk_ORB.txt")]
    with caplog.at_level("WARNING"):
        assert main(args) == 0
    assert "matched poses: 2174" in capsys.readouterr().out
    assert any("dropped 1 poses with duplicate timestamps" in r.getMessage() for r in caplog.records)
    assert main(args + ["--duplicates", "error"]) == 2
    err = capsys.readouterr().err
    assert "fr2_desk_groundtruth.txt:10863: duplicate timestamp" in err and "keep-last" in err


def test_eval_reference_first_and_monocular_default(tum, tmp_path, capsys):
    """REF first; EST from a monocular run folder defaults to Sim(3), and the printout says so."""
    run = tmp_path / "run"
    run.mkdir()
    est = run / "trajectory.txt"
    est.write_text((tum / "freiburg1_xyz-ORB_kf_mono.txt").read_text())
    gt = str(tum / "freiburg1_xyz-groundtruth.txt")
    assert main(["eval", gt, str(est)]) == 0
    out = capsys.readouterr().out
    assert "alignment se3: default" in out and f"ground truth:  {gt}" in out
    (run / "stats.json").write_text(json.dumps({"sensor": "mono"}))
    assert main(["eval", gt, str(est), "--json", str(tmp_path / "r.json")]) == 0
    out = capsys.readouterr().out
    assert "alignment sim3: default for a monocular run" in out
    assert json.loads((tmp_path / "r.json").read_text())["ate_rmse"] == pytest.approx(0.0097546, abs=1e-6)


BAD = {
    "empty": ("", "empty"),
    "malformed": ("1.0 0 0 0 0 0 0 1\n2.0 0 0 x 0 0 0 1\n", ":2: not a number"),
    "unsorted": ("2.0 0 0 0 0 0 0 1\n1.0 0 0 0 0 0 0 1\n", ":2: timestamps are not sorted"),
    "duplicate": ("1.0 0 0 0 0 0 0 1\n1.0 0 0 0 0 0 0 1\n", ":2: duplicate timestamp"),
    "no_overlap": ("1.0 0 0 0 0 0 0 1\n2.0 0 0 0 0 0 0 1\n3.0 1 0 0 0 0 0 1\n", "no common timestamps"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_eval_bad_input_exits_cleanly(tum, tmp_path, capsys, case):
    text, needle = BAD[case]
    est = tmp_path / f"{case}.txt"
    est.write_text(text)
    rc = main(["eval", str(tum / "freiburg1_xyz-groundtruth.txt"), str(est)])
    captured = capsys.readouterr()
    assert rc == 2
    assert needle in captured.err and captured.err.startswith("vslam eval: error: ")
    assert (str(est) in captured.err) and "Traceback" not in captured.err
    assert captured.err.count("\n") == 1


def test_eval_missing_file(tmp_path, capsys):
    rc = main(["eval", str(tmp_path / "gt.txt"), str(tmp_path / "est.txt")])
    err = capsys.readouterr().err
    assert rc == 2 and "est.txt: trajectory file not found" in err and "Traceback" not in err
