"""Fault injection, round 2 (issue #27): a map another command is extending in place, and signals
at the edges of a run (right after its last frame, while its map loads).

As in ``test_faults.py``: real ``vslam`` processes stopped by real signals, each case asserting the
exit status, a single ``vslam ...`` error line, and what is left on disk. A child pauses at a named
function (``VSLAM_TEST_PAUSE=module:attr``, as ``SLOW_MERGE`` does) and says so in a marker file,
so the signal lands exactly there.
"""
from __future__ import annotations

import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

import vslam.outputs
from tests.cli.test_faults import N, ROOT, _env, base_seq, cli, one_error, seq, stats_of, whole_lines  # noqa: F401

PAUSE_AT = """
import importlib, os, pathlib, sys, time
module, _, where = os.environ["VSLAM_TEST_PAUSE"].partition(":")
owner = importlib.import_module(module)
*path, name = where.split(".")
for part in path:
    owner = getattr(owner, part)
real = getattr(owner, name)
def pause(*args, **kwargs):
    pathlib.Path(os.environ["VSLAM_TEST_MARKER"]).write_text(name)
    time.sleep(60)
    return real(*args, **kwargs)
setattr(owner, name, pause)
from vslam.cli import main
sys.exit(main(sys.argv[1:]))
"""


@pytest.fixture(scope="module")
def base_map(tmp_path_factory, base_seq) -> Path:  # noqa: F811
    from vslam.api import run_path

    out = tmp_path_factory.mktemp("mapped") / "M"
    run_path(base_seq, out, sensor="rgbd")
    return out


@pytest.fixture
def map_dir(tmp_path, base_map) -> Path:
    return Path(shutil.copytree(base_map, tmp_path / "M"))


def _paused(tmp: Path, at: str, *argv) -> subprocess.Popen:
    """``vslam ARGV`` in a child process that pauses (60 s) when it calls ``at``; returned once it does."""
    marker = tmp / "paused"
    marker.unlink(missing_ok=True)
    proc = subprocess.Popen([sys.executable, "-c", PAUSE_AT, *map(str, argv)], cwd=ROOT,
                            env={**_env(), "VSLAM_TEST_PAUSE": at, "VSLAM_TEST_MARKER": str(marker)},
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.time() + 120
    while not marker.exists() and time.time() < deadline and proc.poll() is None:
        time.sleep(0.05)
    if not marker.exists():
        proc.kill()
        pytest.fail(f"the child never reached {at}: " + proc.communicate()[1])
    return proc


def _terminate(proc: subprocess.Popen) -> str:
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    one_error(err, proc.returncode, 143, "terminated")
    return err


# -------------------------------------------------------------------------------- concurrency
def test_a_map_extended_in_place_is_named_then_read_from_previous_run(capsys, caplog, tmp_path, seq, map_dir,
                                                                      monkeypatch):
    keyframes = stats_of(map_dir)["keyframes"]
    other = Path(shutil.copytree(map_dir, tmp_path / "other"))
    proc = _paused(tmp_path, "vslam.system:System.save_map_outputs", "run", seq, "--map", map_dir, "-o", map_dir,
                   "--no-progress", "--sensor", "rgbd")  # extending M in place: its map is in M/.previous-run
    try:
        monkeypatch.setattr(vslam.outputs, "READ_WAIT_S", 0.5)
        for argv in (["localize", map_dir, seq, "-o", tmp_path / "loc", "--no-progress"],
                     ["run", seq, "--map", map_dir, "-o", tmp_path / "run", "--no-progress", "--sensor", "rgbd"],
                     ["merge", other, map_dir, "-o", tmp_path / "merged"]):
            caplog.clear()
            rc, _, err = cli(capsys, *argv)
            one_error(err, rc, 2, str(map_dir), "is being written by another command", "`vslam run",
                      f"--map {map_dir}", f"pid {proc.pid}")
            assert caplog.text.count("waiting up to 0.5 s") == 1  # said once, before the wait
            assert not (argv[argv.index("-o") + 1] / "stats.json").exists()
    finally:
        _terminate(proc)  # the in-place run stopped: the last complete map stays in M/.previous-run
    assert stats_of(map_dir)["error"] == "terminated (SIGTERM)"
    assert not (map_dir / "map").exists() and (map_dir / ".previous-run" / "map" / "map.json").is_file()

    caplog.clear()
    rc, out, err = cli(capsys, "localize", map_dir, seq, "-o", tmp_path / "loc2", "--no-progress")
    assert rc == 0, err
    assert "did not complete (stats.json: terminated (SIGTERM))" in caplog.text and ".previous-run" in caplog.text
    assert stats_of(tmp_path / "loc2")["map_keyframes"] == keyframes and "error" not in stats_of(tmp_path / "loc2")

    # a rerun in place after the stopped one: continues the last complete map, and completes
    rc, out, err = cli(capsys, "run", seq, "--map", map_dir, "-o", map_dir, "--no-progress", "--sensor", "rgbd",
                       "--max-frames", "4")
    assert rc == 0, err
    assert "error" not in stats_of(map_dir) and stats_of(map_dir)["map_keyframes_loaded"] == keyframes
    assert (map_dir / "map" / "map.json").is_file() and not (map_dir / ".previous-run").exists()


def test_a_reader_waits_for_the_writer(capsys, caplog, tmp_path, seq, map_dir, monkeypatch):
    import filelock

    lock = filelock.FileLock(str(map_dir / ".vslam.lock"), thread_local=False)
    lock.acquire()
    (map_dir / ".vslam.lock.owner").write_text('{"command": "vslam run x --map M -o M", "pid": 1, "since": "now"}')
    threading.Timer(1.0, lock.release).start()  # the writer finishes within the wait
    monkeypatch.setattr(vslam.outputs, "READ_WAIT_S", 60)
    t0 = time.monotonic()
    rc, out, err = cli(capsys, "localize", map_dir, seq, "-o", tmp_path / "loc", "--no-progress")
    assert rc == 0, err
    assert time.monotonic() - t0 >= 0.9
    warning = [r.getMessage() for r in caplog.records if "waiting up to 60 s" in r.getMessage()]
    assert len(warning) == 1 and "`vslam run x --map M -o M`, pid 1" in warning[0]
    assert stats_of(tmp_path / "loc")["frames"] == N


# ------------------------------------------------------------------------------------ signals
@pytest.mark.parametrize("at,map_written", [("vslam.system:System.save_map_outputs", False),
                                            ("vslam.runner:trajectory_errors", True),
                                            ("vslam.api:_trajectory_png", True)])  # after stats.json
def test_sigterm_while_the_outputs_are_written(tmp_path, seq, at, map_written):
    out = tmp_path / "run"
    proc = _paused(tmp_path, at, "run", seq, "-o", out, "--no-progress", "--sensor", "rgbd")
    _terminate(proc)  # after the last frame: never a complete trajectory beside no stats.json and no map/
    stats = stats_of(out)
    assert stats["error"] == "terminated (SIGTERM)" and stats["frames"] == N
    assert len(whole_lines(out / "trajectory.txt")) == N + 1
    assert (out / "map" / "map.json").is_file() == map_written
    assert not [p for p in out.iterdir() if ".tmp-" in p.name]


@pytest.mark.parametrize("in_place", [True, False])
def test_sigterm_while_the_map_loads(capsys, caplog, tmp_path, seq, map_dir, in_place):
    out = map_dir if in_place else tmp_path / "run"
    proc = _paused(tmp_path, "vslam.map.io:load_map", "run", seq, "--map", map_dir, "-o", out, "--no-progress",
                   "--sensor", "rgbd")
    _terminate(proc)
    stats = stats_of(out)
    assert stats["error"] == "terminated (SIGTERM)" and stats["map"] == str(map_dir.resolve())
    assert not (out / "trajectory.txt").exists()
    if in_place:  # the map is kept whole, and read from there with a warning
        assert (map_dir / ".previous-run" / "map" / "map.json").is_file()
        rc, _, err = cli(capsys, "localize", map_dir, seq, "-o", tmp_path / "loc", "--no-progress")
        assert rc == 0, err
        assert "kept in " + str(map_dir / ".previous-run") in caplog.text
    else:
        assert (map_dir / "map" / "map.json").is_file() and "error" not in stats_of(map_dir)


def test_a_signal_while_stats_json_is_written_waits_for_it(capsys, tmp_path, seq, monkeypatch):
    import os

    import vslam.runner

    out, real = tmp_path / "run", vslam.runner._write_json

    def write(path, data):
        if path.name == "stats.json":
            os.kill(os.getpid(), signal.SIGTERM)  # its handler runs once stats.json is whole
        real(path, data)

    monkeypatch.setattr(vslam.runner, "_write_json", write)
    rc, _, err = cli(capsys, "run", seq, "-o", out, "--no-progress", "--sensor", "rgbd")
    one_error(err, rc, 143, "terminated")
    assert stats_of(out)["frames"] == N and (out / "map" / "map.json").is_file()
