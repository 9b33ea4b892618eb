"""Fault injection, round 2 continued (issue #27): every number a user gives is checked where it
enters (settings ranges, trajectory magnitudes, bench specs), maps are checked for meaning on load,
ROS bag stamps must increase, and ``vslam merge`` / ``vslam localize`` stopped by a signal leave a
``stats.json`` with the error, as ``vslam run`` does.

As in ``test_faults.py``: each case asserts the exit status, a single ``vslam ...`` error line that
names the file (and key), no traceback, and that nothing was lost on disk.
"""
from __future__ import annotations

import dataclasses
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from tests.cli.test_faults import ROOT, _env, base_seq, cli, one_error, run_args, seq, stats_of  # noqa: F401
from tests.cli.test_faults_outputs import TRAJ, _snapshot

CAMERA_ARGS = (262.5, 262.5, 159.5, 119.5, 320, 240)


# ----------------------------------------------------------------------------------- settings
BAD_SETTINGS = {  # name: (extra run arguments from tmp, words of the error line)
    "n_levels 10^8": (lambda tmp: ["--set", "features.n_levels=100000000"], ("features.n_levels", "[1, 32]")),
    "patch_size 100001": (lambda tmp: ["--set", "features.patch_size=100001"], ("features.patch_size", "[7, 255]")),
    "a ratio over 1": (lambda tmp: ["--set", "frontend.matching.match_ratio=7"],
                       ("frontend.matching.match_ratio", "(0, 1]")),
    "negative iterations": (lambda tmp: ["--set", "backend.local.iterations_refine=-5"],
                            ("backend.local.iterations_refine", "[0, 1000]")),
    "--config: a window of 10^5": (lambda tmp: ["--config", _file(tmp / "c.yaml", "frontend:\n  klt:\n"
                                                                   "    window: 100000\n")],
                                   ("c.yaml", "frontend.klt.window", "[3, 101]")),
    "--config: an alias bomb": (lambda tmp: ["--config", _file(tmp / "c.yaml", "a: &a [1, 1, 1, 1, 1, 1, 1, 1]\n"
                                                               "b: &b [*a, *a, *a, *a, *a, *a, *a, *a]\n")],
                                ("c.yaml:2", "alias")),
    "--config over 1 MB": (lambda tmp: ["--config", _file(tmp / "c.yaml", "#" * 1_100_000 + "\n")],
                           ("c.yaml", "bytes")),
}


def _file(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


@pytest.mark.parametrize("case", list(BAD_SETTINGS))
def test_settings_out_of_range_are_refused(capsys, seq, tmp_path, case):
    make, words = BAD_SETTINGS[case]
    out = tmp_path / "run"
    rc, _, err = cli(capsys, *run_args(seq, out, *make(tmp_path)))
    one_error(err, rc, 2, *words)
    assert not (out / "trajectory.txt").exists()  # refused before any frame


def test_every_numeric_setting_declares_its_range():
    from vslam.config import Config, check_bounds, iter_settings
    from vslam.param import Bounds

    numbers = [s for s in iter_settings(Config) if not isinstance(s.default, (bool, str))
               and (s.default is None and s.type.startswith(("int", "float")) or isinstance(s.default, (int, float, tuple)))]
    assert len(numbers) > 200
    missing = [s.key for s in numbers if not s.bounds]
    assert not missing, f"declare param(..., bounds='[lo, hi]') for {missing}"
    for s in numbers:
        assert Bounds.parse(s.bounds).contains(s.default), (s.key, s.default, s.bounds)
    check_bounds(Config())  # the defaults hold
    settings_md = (ROOT / "docs" / "settings.md").read_text()
    assert "| `n_levels` | int | `8` | `[1, 32]` |" in settings_md and "| `gate_chi2` | float | `.inf` | `(0, inf]` |" in \
        settings_md


def test_a_range_holds_for_tuples_and_the_edges():
    from vslam.config import Config, load_config
    from vslam.errors import ConfigError

    cfg = load_config(Config, None, ["features.n_levels=32", "frontend.matching.match_ratio=1",
                                     "backend.ekf.gate_chi2=.inf", "features.gftt_quality=1e-3"])
    assert cfg.features.n_levels == 32 and cfg.features.gftt_quality == 1e-3
    for bad, words in (("frontend.dense.icp_iterations=[7, 0]", "[1, 1000]"),
                       ("frontend.matching.match_ratio=0", "(0, 1]"), ("features.scale_factor=1", "(1, 4]")):
        with pytest.raises(ConfigError, match=words.replace("[", r"\[").replace("(", r"\(")):
            load_config(Config, None, [bad])
    with pytest.raises(ConfigError, match="alias"):
        load_config(Config, None, ["features.n_levels=[&a [1, 1], *a]"])


# ------------------------------------------------------------------------------- trajectories
def _traj_with(line: int, text: str) -> str:
    rows = TRAJ.splitlines(keepends=True)
    rows[line - 1] = text
    return "".join(rows)


@pytest.mark.parametrize("row,words", [("2 1e200 0 0 0 0 0 1\n", ("position", "1e+200")),
                                       ("2 0 0 -3e15 0 0 0 1\n", ("position",)),
                                       ("1e300 0 0 0 0 0 0 1\n", ("timestamp",)),
                                       ("2 nan 0 0 0 0 0 1\n", ("NaN",))])
def test_trajectory_magnitudes_are_checked_where_they_enter(capsys, tmp_path, row, words):
    gt, est = tmp_path / "gt.txt", tmp_path / "est.txt"
    gt.write_text(_traj_with(3, row))
    est.write_text(TRAJ)
    before = _snapshot(gt, est)
    rc, out, err = cli(capsys, "eval", gt, est, "--json", tmp_path / "ate.json")
    one_error(err, rc, 2, f"{gt}:3", *words)
    assert not (tmp_path / "ate.json").exists() and _snapshot(gt, est) == before


def test_kitti_and_euroc_magnitudes(tmp_path):
    from vslam.errors import TrajectoryError
    from vslam.trajectory import read_euroc, read_kitti

    (tmp_path / "k.txt").write_text("1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 5e13 0 1 0 0 0 0 1 0\n")
    with pytest.raises(TrajectoryError, match=r"k.txt:2: a pose entry"):
        read_kitti(tmp_path / "k.txt")
    (tmp_path / "e.csv").write_text("#t,x,y,z,qw,qx,qy,qz\n1403636579758555392,0,0,0,1,0,0,0\n"
                                    "1403636579763555584,0,-1e200,0,1,0,0,0\n")
    with pytest.raises(TrajectoryError, match=r"e.csv:3: a position"):
        read_euroc(tmp_path / "e.csv")


def _strict_json(text: str):
    def refuse(name):
        raise AssertionError(f"{name} is not JSON")
    return json.loads(text, parse_constant=refuse)


def test_eval_json_is_strict_json(capsys, tmp_path, monkeypatch):
    from vslam.eval.evaluate import EvalResult
    from vslam.outputs import strict_json

    real = EvalResult.to_dict  # a metric that overflowed or had no sample: null, never Infinity / NaN
    monkeypatch.setattr(EvalResult, "to_dict", lambda self: {**real(self), "ate_max": float("inf"),
                                                             "rpe_trans_std": float("nan")})
    gt, est = tmp_path / "gt.txt", tmp_path / "est.txt"
    gt.write_text(TRAJ)
    est.write_text(TRAJ)
    rc, _, err = cli(capsys, "eval", gt, est, "--json", tmp_path / "ate.json")
    assert rc == 0, err
    data = _strict_json((tmp_path / "ate.json").read_text())
    assert data["ate_rmse"] == pytest.approx(0.0, abs=1e-6) and data["ate_max"] is None and data["rpe_trans_std"] is None
    assert _strict_json(strict_json({"a": float("inf"), "b": np.float64("nan"), "c": np.array([1.0, -np.inf]),
                                     "d": [np.int64(3)]})) == {"a": None, "b": None, "c": [1.0, None], "d": [3]}


# ---------------------------------------------------------------------------------- bench specs
def _spec(tmp: Path, text: str) -> Path:
    (tmp / "data").mkdir(exist_ok=True)
    spec = tmp / "spec.yaml"
    spec.write_text(text)
    return spec


BAD_SPECS = {  # name: (spec text, prepare(tmp), words of the error line)
    "data a symlink loop": ("runs:\n  - {name: r1, data: loop}\n",
                            lambda tmp: (tmp / "loop").symlink_to(tmp / "loop"), ("spec.yaml", "r1", "link loop")),
    "config the spec itself": ("runs:\n  - {name: r1, data: data, config: spec.yaml}\n", lambda tmp: None,
                               ("spec.yaml", "r1", "config", "spec itself")),
    "repeats 10^9": ("repeats: 1000000000\nruns:\n  - {name: r1, data: data}\n", lambda tmp: None,
                     ("spec.yaml", "repeats", "<= 1000")),
    "a run's repeats 10^9": ("runs:\n  - {name: r1, data: data, repeats: 1000000000}\n", lambda tmp: None,
                             ("spec.yaml", "r1", "repeats", "<= 1000")),
    "a setting out of range": ("runs:\n  - {name: r1, data: data, set: {features.n_levels: 100000000}}\n",
                               lambda tmp: None, ("spec.yaml", "r1", "features.n_levels", "[1, 32]")),
    "a missing data folder": ("runs:\n  - {name: r1, data: nowhere}\n", lambda tmp: None,
                              ("spec.yaml", "r1", "does not exist")),
    "an alias bomb": ("a: &a [1, 1, 1, 1, 1, 1, 1, 1]\nb: [*a, *a, *a, *a]\nruns: []\n", lambda tmp: None,
                      ("spec.yaml:2", "alias")),
}


@pytest.mark.parametrize("dry_run", [True, False], ids=["--dry-run", "real"])
@pytest.mark.parametrize("case", list(BAD_SPECS))
def test_bench_dry_run_checks_the_spec_as_the_real_run(capsys, tmp_path, case, dry_run):
    text, prepare, words = BAD_SPECS[case]
    spec = _spec(tmp_path, text)
    prepare(tmp_path)
    before = _snapshot(spec)
    rc, _, err = cli(capsys, "bench", spec, "-o", tmp_path / "b", "--workers", "0", "--no-plots",
                     *(["--dry-run"] if dry_run else []))
    one_error(err, rc, 2, *words)
    assert not (tmp_path / "b").exists() and _snapshot(spec) == before


def test_bench_dry_run_still_takes_its_fake_settings(capsys, tmp_path):
    spec = _spec(tmp_path, "runs:\n  - {name: r1, data: data, set: {fake.fps: 20, features.n_levels: 4}}\n")
    rc, _, err = cli(capsys, "bench", spec, "-o", tmp_path / "b", "--dry-run", "--workers", "0", "--no-plots")
    assert rc == 0, err
    rc, _, err = cli(capsys, "bench", spec, "-o", tmp_path / "b", "--dry-run", "--repeats", "1001")
    one_error(err, rc, 2, "--repeats", "1000")


# ------------------------------------------------------------------------------ maps (meaning)
def _camera():
    from vslam.geometry.camera import PinholeCamera

    return PinholeCamera(*CAMERA_ARGS)


def _saved_map(root: Path, slam_map) -> Path:
    from vslam.map.io import save_map

    save_map(slam_map, root, camera=_camera(), metadata={"sensor": "rgbd"})
    return root


def _empty_map(tmp: Path) -> tuple[Path, str]:
    from vslam.map.map import Map

    return _saved_map(tmp / "M", Map()), "no keyframes"


def _nan_points(tmp: Path) -> tuple[Path, str]:
    from tests.map._builders import random_map

    slam_map = random_map(1, mode="orb")
    alive = np.flatnonzero(slam_map.points.alive[: len(slam_map.points)])
    slam_map.points.position[alive[3]] = np.nan  # saved with consistent checksums
    return _saved_map(tmp / "M", slam_map), "points.npz"


@pytest.mark.parametrize("command", ["run --map", "localize"])
@pytest.mark.parametrize("make", [_empty_map, _nan_points], ids=["zero keyframes", "NaN point positions"])
def test_maps_are_checked_for_meaning_on_load(capsys, seq, tmp_path, command, make):
    root, words = make(tmp_path)
    before = _snapshot(root)
    out = tmp_path / "out"
    argv = run_args(seq, out, "--map", root) if command == "run --map" else \
        ["localize", root, seq, "-o", out, "--no-progress"]
    rc, _, err = cli(capsys, *argv)
    one_error(err, rc, 2, str(root), words)
    assert _snapshot(root) == before
    assert not (out / "trajectory.txt").exists() or "error" in stats_of(out)


# ------------------------------------------------------------------------------------- ROS bags
@pytest.mark.parametrize("stamp,words", [(lambda k, t: 0.0, ("all 9 header stamps are 0.000000000 s",)),
                                         (lambda k, t: t - 0.5 * (k == 4), ("not increasing", "message 5"))],
                         ids=["all zero", "one going back"])
def test_bag_stamps_must_increase(capsys, shared_data, tmp_path, stamp, words):
    pytest.importorskip("rosbags")
    from tests.datasets.test_rosbag import _write_bag

    bag = _write_bag(shared_data / "tum_rgbd_freiburg1_desk_9frames", tmp_path / "bag", ros1=False, color_stamp=stamp)
    rc, _, err = cli(capsys, "run", bag, "-o", tmp_path / "out", "--no-progress")
    one_error(err, rc, 2, str(bag), "/camera/rgb/image_color", *words)


# ------------------------------------------------------------------------------------- signals
def _two_maps(tmp: Path) -> tuple[Path, Path]:
    from tests.map._builders import random_map

    return _saved_map(tmp / "A", random_map(1, mode="orb")), _saved_map(tmp / "B", random_map(2, mode="orb"))


def _previous_complete(out: Path) -> dict:
    out.mkdir()
    (out / "stats.json").write_text(json.dumps({"keyframes": 7}))
    (out / "keyframes.txt").write_text(TRAJ)
    return _snapshot(out)


def _interrupt(signum: int):
    from vslam.signals import Interrupted

    def stop(*args, **kwargs):
        raise Interrupted(signum)
    return stop


@pytest.mark.parametrize("where", ["merging", "loading map B"])
def test_a_stopped_merge_writes_its_error(capsys, tmp_path, monkeypatch, where):
    import vslam.map.io
    import vslam.merge

    a, b = _two_maps(tmp_path)
    out = tmp_path / "AB"
    good = _previous_complete(out)
    if where == "merging":
        monkeypatch.setattr(vslam.merge, "merge_maps", _interrupt(signal.SIGTERM))
    else:
        real = vslam.map.io.load_run_map
        monkeypatch.setattr(vslam.map.io, "load_run_map", lambda path, *args, **kw: (
            _interrupt(signal.SIGTERM)() if Path(path) == b else real(path, *args, **kw)))
    rc, _, err = cli(capsys, "merge", a, b, "-o", out)
    one_error(err, rc, 143, "terminated")
    stats = stats_of(out)
    assert stats["error"] == "terminated (SIGTERM)" and stats["map_b"] == str(b.resolve())
    prev = out / ".previous-run"  # the last complete merge kept whole
    assert _snapshot(prev) == {k.replace(str(out), str(prev)): v for k, v in good.items()}


def test_a_stopped_localize_writes_its_error(capsys, seq, tmp_path, monkeypatch):
    import vslam.localize

    out = tmp_path / "loc"
    monkeypatch.setattr(vslam.localize, "open_map", _interrupt(signal.SIGINT))
    rc, _, err = cli(capsys, "localize", tmp_path / "M", seq, "-o", out, "--no-progress")
    one_error(err, rc, 130, "interrupted")
    assert stats_of(out)["error"] == "interrupted"


SLOW_MERGE = """
import os, pathlib, sys, time
import vslam.merge
def slow(*args, **kwargs):
    pathlib.Path(os.environ["VSLAM_TEST_MARKER"]).write_text("merging")
    time.sleep(60)
vslam.merge.merge_maps = slow
from vslam.cli import main
sys.exit(main(sys.argv[1:]))
"""


@pytest.mark.parametrize("sig,rc,word", [(signal.SIGTERM, 143, "terminated (SIGTERM)"),
                                         (signal.SIGINT, 130, "interrupted")])
def test_a_signal_stops_a_merge_cleanly(tmp_path, sig, rc, word):
    a, b = _two_maps(tmp_path)
    out, marker = tmp_path / "AB", tmp_path / "marker"
    proc = subprocess.Popen([sys.executable, "-c", SLOW_MERGE, "merge", str(a), str(b), "-o", str(out)], cwd=ROOT,
                            env={**_env(), "VSLAM_TEST_MARKER": str(marker)}, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.time() + 60
    while not marker.exists() and time.time() < deadline and proc.poll() is None:
        time.sleep(0.05)
    assert marker.exists(), proc.communicate()[1]
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=60)
    one_error(err, proc.returncode, rc, word.split()[0])
    assert stats_of(out)["error"] == word
    assert not (out / "map").exists() and not [p for p in out.iterdir() if ".tmp-" in p.name]
