"""Fault injection: bad inputs, hostile files, full disks, signals and busy run folders.

Every case asserts the exit status, a single ``vslam ...`` error line without a traceback, and what
is left on disk (nothing half-written, nothing from another run). Sequences are tiny TUM folders
rendered by the synthetic writer (12 frames of 320x240) and copied into ``tmp_path``, so the whole file runs in well under a minute.
"""
from __future__ import annotations

import errno
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from vslam.cli import main
from vslam.datasets.synthetic import SyntheticConfig, render_sequence
from vslam.errors import GeometryError, MapFormatError, OutputError, VslamError
from vslam.outputs import LineWriter, atomic_write_text, inside, open_run_dir

ROOT = Path(__file__).resolve().parents[2]
N = 12


@pytest.fixture(scope="module")
def base_seq(tmp_path_factory) -> Path:
    """12 synthetic RGB-D frames (320x240) that track completely."""
    cfg = SyntheticConfig(n_frames=N, width=320, height=240, fx=262.5, fy=262.5, cx=159.5, cy=119.5,
                          stereo=False, seed=3)
    return render_sequence(tmp_path_factory.mktemp("base") / "seq", cfg)


@pytest.fixture
def seq(tmp_path, base_seq) -> Path:
    return Path(shutil.copytree(base_seq, tmp_path / "seq"))


def cli(capsys, *argv) -> tuple[int, str, str]:
    rc = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return rc, out, err


def one_error(err: str, rc: int, want_rc: int, *words: str) -> str:
    """The single ``vslam`` error line of ``err``; checks the status, no traceback, and ``words``."""
    assert "Traceback" not in err, err
    assert rc == want_rc, (rc, err)
    lines = [ln for ln in err.splitlines() if ln.startswith("vslam ")]
    assert len(lines) == 1, err
    for w in words:
        assert w in lines[0], (w, lines[0])
    return lines[0]


def run_args(seq: Path, out: Path, *extra) -> list:
    return ["run", seq, "-o", out, "--no-progress", "--sensor", "rgbd", *extra]


def stats_of(out: Path) -> dict:
    return json.loads((out / "stats.json").read_text())


def whole_lines(path: Path) -> list[str]:
    text = path.read_text()
    assert text == "" or text.endswith("\n"), repr(text[-40:])
    for ln in text.splitlines():
        if not ln.startswith("#"):
            assert len(ln.split()) == 8 and all(np.isfinite(float(v)) for v in ln.split()), ln
    return text.splitlines()


# ------------------------------------------------------------------------------------ outputs
OUTPUT_CASES = {
    "existing file": (lambda seq, tmp: (tmp / "f.txt").write_text("x") and tmp / "f.txt", "not a folder"),
    "under a file": (lambda seq, tmp: (tmp / "f.txt").write_text("x") and tmp / "f.txt" / "run", "is a file"),
    "the input folder": (lambda seq, tmp: seq, "is the input"),
    "the image folder": (lambda seq, tmp: seq / "rgb", "holds images"),
    "the depth folder": (lambda seq, tmp: seq / "depth", "holds images"),
}


@pytest.mark.parametrize("case", list(OUTPUT_CASES))
def test_bad_output_folder(capsys, seq, tmp_path, case):
    make, words = OUTPUT_CASES[case]
    before = sorted(p.name for p in (seq / "rgb").iterdir())
    out = make(seq, tmp_path)
    rc, _, err = cli(capsys, *run_args(seq, out))
    one_error(err, rc, 2, words)
    assert sorted(p.name for p in (seq / "rgb").iterdir()) == before  # nothing written among the inputs
    assert not (seq / "trajectory.txt").exists() and not (seq / "rgb" / "stats.json").exists()


@pytest.mark.skipif(os.geteuid() == 0, reason="root ignores permissions")
def test_read_only_output_folder(capsys, seq, tmp_path):
    out = tmp_path / "ro"
    out.mkdir()
    out.chmod(0o500)
    rc, _, err = cli(capsys, *run_args(seq, out / "sub"))
    one_error(err, rc, 2, "Permission denied")


def test_a_folder_in_use_is_refused(capsys, seq, tmp_path):
    import filelock

    out = tmp_path / "run"
    out.mkdir()
    with filelock.FileLock(str(out / ".vslam.lock")):
        rc, _, err = cli(capsys, *run_args(seq, out))
    one_error(err, rc, 2, "another vslam run")
    assert sorted(p.name for p in out.iterdir()) == [".vslam.lock"]


def test_two_processes_never_share_a_folder(tmp_path, seq):
    out = tmp_path / "run"
    holder = open_run_dir(out)
    try:  # a second process (a concurrent `vslam run`) is refused while this one holds the folder
        proc = subprocess.run([sys.executable, "-m", "vslam", "run", str(seq), "-o", str(out), "--no-progress"],
                              capture_output=True, text=True, cwd=ROOT, env=_env(), timeout=120)
    finally:
        holder.release()
    one_error(proc.stderr, proc.returncode, 2, "another vslam run")
    assert not (out / "stats.json").exists()


OLD_OUTPUTS = ("map/map.json", "keyframes.txt", "sparse.ply", "topology.json", "topology.png", "trajectory.txt",
               "stats.json")


def _old_run(out: Path) -> None:
    for name in OLD_OUTPUTS:
        (out / name).parent.mkdir(parents=True, exist_ok=True)
        (out / name).write_text("old\n")


def test_interrupted_rerun_never_mixes_runs(capsys, seq, tmp_path, monkeypatch):
    out = tmp_path / "run"
    _old_run(out)
    from vslam.system import System

    real = System.track

    def track(self, frame):
        if frame.index == 3:
            raise KeyboardInterrupt
        return real(self, frame)

    monkeypatch.setattr(System, "track", track)
    rc, _, err = cli(capsys, *run_args(seq, out))
    one_error(err, rc, 130, "interrupted")
    assert stats_of(out)["error"] == "interrupted" and stats_of(out)["frames"] == 3
    for name in ("map", "keyframes.txt", "sparse.ply", "topology.json", "topology.png"):
        assert not (out / name).exists(), name  # nothing of the old run beside the new stats
    assert (out / ".previous-run" / "map" / "map.json").read_text() == "old\n"  # kept, not lost
    whole_lines(out / "trajectory.txt")


def test_successful_rerun_replaces_the_old_run(capsys, seq, tmp_path):
    out = tmp_path / "run"
    _old_run(out)
    rc, outp, err = cli(capsys, *run_args(seq, out))
    assert rc == 0, err
    assert not (out / ".previous-run").exists()
    assert stats_of(out)["frames"] == N and "error" not in stats_of(out)
    assert (out / "keyframes.txt").read_text() != "old\n"
    rc, _, err = cli(capsys, *run_args(seq, out, "--max-frames", "3"))  # a real run folder, run again
    assert rc == 0, err
    assert stats_of(out)["frames"] == 3 and not (out / ".previous-run").exists()


@pytest.mark.parametrize("flag", ["--json", "--plot"])
def test_eval_output_that_is_a_folder(capsys, tmp_path, flag):
    traj = tmp_path / "t.txt"
    traj.write_text("".join(f"{i} {0.1 * i} 0 0 0 0 0 1\n" for i in range(10)))
    rc, out, err = cli(capsys, "eval", traj, traj, flag, tmp_path)
    one_error(err, rc, 2, "is a folder")
    assert out == ""  # refused before any work is printed


# --------------------------------------------------------------------------------- full disk
class _FullDisk:
    """A raw file that accepts ``room`` bytes, then writes short (or raises ENOSPC)."""

    def __init__(self, fh, room: int, raise_: bool):
        self.fh, self.room, self.raise_ = fh, room, raise_

    def write(self, data):
        if len(data) <= self.room:
            self.room -= len(data)
            return self.fh.write(data)
        if self.raise_:
            raise OSError(errno.ENOSPC, "No space left on device")
        n = self.fh.write(data[: self.room])
        self.room = 0
        return n

    def truncate(self, n):
        return self.fh.truncate(n)

    def close(self):
        self.fh.close()


@pytest.mark.parametrize("room", [0, 10, 60, 75, 130])
@pytest.mark.parametrize("raise_", [True, False], ids=["ENOSPC", "short-write"])
def test_line_writer_keeps_whole_lines(tmp_path, room, raise_):
    path = tmp_path / "trajectory.txt"
    w = LineWriter(path)
    w._fh = _FullDisk(w._fh, room, raise_)
    lines = [f"{i}.000000 {i} 2 3 0 0 0 1\n" for i in range(10)]
    with pytest.raises(OutputError, match="trajectory.txt: cannot write .*free space"):
        for ln in lines:
            w.write(ln)
    w.close()
    text = path.read_text()
    assert text == "".join(lines[: len(text.splitlines())])  # a prefix of whole lines


def test_atomic_write_keeps_the_old_file(tmp_path, monkeypatch):
    path = tmp_path / "stats.json"
    path.write_text("old")

    def full(fd, data):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr("vslam.outputs._raw_write", full)
    with pytest.raises(OutputError, match="stats.json: cannot write"):
        atomic_write_text(path, "new")
    monkeypatch.undo()
    assert path.read_text() == "old" and [p.name for p in tmp_path.iterdir()] == ["stats.json"]


def test_disk_full_while_tracking(capsys, seq, tmp_path, monkeypatch):
    out = tmp_path / "run"
    real_init = LineWriter.__init__

    def init(self, path):
        real_init(self, path)
        self._fh = _FullDisk(self._fh, 200, False)

    monkeypatch.setattr(LineWriter, "__init__", init)
    rc, _, err = cli(capsys, *run_args(seq, out))
    one_error(err, rc, 2, "trajectory.txt", "free space")
    assert "trajectory.txt" in stats_of(out)["error"]
    assert 1 <= len(whole_lines(out / "trajectory.txt")) < N


def test_map_save_failure_is_an_error(capsys, seq, tmp_path, monkeypatch):
    from vslam.system import System

    def full(self, out, metadata=None, progress=None):
        raise OSError(errno.ENOSPC, "No space left on device", str(out / "map"))

    monkeypatch.setattr(System, "save_map_outputs", full)
    out = tmp_path / "run"
    rc, _, err = cli(capsys, *run_args(seq, out))
    one_error(err, rc, 2, "map", "No space left on device")
    assert "No space left" in stats_of(out)["error"] and stats_of(out)["frames"] == N
    whole_lines(out / "trajectory.txt")


@pytest.mark.parametrize("limit,first_failure", [(1000, "config.yaml"), (10_000, "run"), (200_000, "map")])
def test_file_size_limit_in_a_real_process(tmp_path, seq, limit, first_failure):
    """RLIMIT_FSIZE makes the kernel refuse writes past ``limit`` bytes per file (EFBIG), as a full
    disk would: config.yaml (4.7 KB), then sparse.ply / topology.png (~45 KB), then the map's arrays."""
    import resource

    out = tmp_path / "run"

    def limit_files():
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    proc = subprocess.run([sys.executable, "-m", "vslam", "run", str(seq), "-o", str(out), "--no-progress"],
                          capture_output=True, text=True, cwd=ROOT, env=_env(), timeout=120, preexec_fn=limit_files)
    line = one_error(proc.stderr, proc.returncode, 2, "cannot write (File too large)", first_failure)
    assert not [p for p in out.rglob("*") if ".tmp" in p.name]  # no temporary file left behind
    if first_failure == "config.yaml":
        assert not (out / "config.yaml").exists() and not (out / "trajectory.txt").exists()
    else:
        assert len(whole_lines(out / "trajectory.txt")) == N + 1
        assert stats_of(out)["error"] in line and stats_of(out)["frames"] == N


# ------------------------------------------------------------------------------------ signals
def _env() -> dict:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return env


SLOW_RUN = """
import sys, time
import vslam.datasets.prefetch as pf
pf.PROCESS_MIN_PIXELS = 1
pf.PROCESS_HEAD_FRAMES = 0
from vslam.system import System
real = System.track
def track(self, frame):
    time.sleep(0.3)
    return real(self, frame)
System.track = track
from vslam.cli import main
sys.exit(main(sys.argv[1:]))
"""


def _children(pid: int) -> set[int]:
    try:
        text = Path(f"/proc/{pid}/task/{pid}/children").read_text()
    except OSError:
        return set()
    return {int(c) for c in text.split()}


def _alive(pid: int) -> bool:
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"


def _start_slow(seq: Path, out: Path):
    # the run starts with SIGINT at its default disposition whatever this process inherited (Python
    # leaves an inherited SIG_IGN in place, as under `nohup` or a non-interactive shell's `&`)
    proc = subprocess.Popen([sys.executable, "-c", SLOW_RUN, "run", str(seq), "-o", str(out), "--no-progress",
                             "--sensor", "rgbd"], cwd=ROOT, env=_env(), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.time() + 60
    while time.time() < deadline:
        traj = out / "trajectory.txt"
        if traj.exists() and len(traj.read_text().splitlines()) >= 3 and _children(proc.pid):
            return proc
        time.sleep(0.1)
    proc.kill()
    pytest.fail("the run did not start: " + proc.communicate()[1])


@pytest.mark.parametrize("sig,rc,word", [(signal.SIGTERM, 143, "terminated"), (signal.SIGINT, 130, "interrupted"),
                                         (signal.SIGHUP, 129, "terminated")])
def test_signal_stops_cleanly(tmp_path, seq, sig, rc, word):
    out = tmp_path / "run"
    proc = _start_slow(seq, out)
    kids = _children(proc.pid)
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=60)
    one_error(err, proc.returncode, rc, word)
    assert word in stats_of(out)["error"]
    whole_lines(out / "trajectory.txt")
    deadline = time.time() + 10
    while time.time() < deadline and any(_alive(k) for k in kids):
        time.sleep(0.1)
    assert not any(_alive(k) for k in kids)


def test_sigkill_leaves_no_orphans(tmp_path, seq):
    out = tmp_path / "run"
    proc = _start_slow(seq, out)
    kids = _children(proc.pid)
    assert kids
    proc.kill()
    proc.communicate(timeout=30)
    deadline = time.time() + 10
    while time.time() < deadline and any(_alive(k) for k in kids):
        time.sleep(0.1)
    assert not any(_alive(k) for k in kids)  # the prefetch child and resource tracker follow their parent
    whole_lines(out / "trajectory.txt")


# ------------------------------------------------------------------------------------- frames
def _png_of_size(w: int, h: int) -> bytes:
    """A small PNG whose header claims ``w x h`` (CRC fixed), as a decompression bomb would."""
    import zlib

    data = bytearray(cv2.imencode(".png", np.zeros((4, 4), np.uint8))[1].tobytes())
    data[16:20], data[20:24] = w.to_bytes(4, "big"), h.to_bytes(4, "big")
    data[29:33] = zlib.crc32(bytes(data[12:29])).to_bytes(4, "big")
    return bytes(data)


def _rgb(seq: Path, i: int) -> Path:
    return sorted((seq / "rgb").iterdir())[i]


def _depth(seq: Path, i: int) -> Path:
    return sorted((seq / "depth").iterdir())[i]


SKIPPED_FRAME = {
    "garbage bytes": lambda seq: _rgb(seq, 4).write_bytes(b"not an image at all"),
    "empty file": lambda seq: _rgb(seq, 4).write_bytes(b""),
    "truncated JPEG": lambda seq: _rgb(seq, 4).write_bytes(cv2.imencode(".jpg", np.zeros((240, 320), np.uint8))[1]
                                                            .tobytes()[:-50]),
    "truncated PNG": lambda seq: _rgb(seq, 4).write_bytes(_rgb(seq, 4).read_bytes()[:300]),
    "depth garbage": lambda seq: _depth(seq, 4).write_bytes(b"\x89PNG garbage"),
    "wrong image size": lambda seq: cv2.imwrite(str(_rgb(seq, 4)), np.zeros((40, 30, 3), np.uint8)),
    "RGBA wrong size": lambda seq: cv2.imwrite(str(_rgb(seq, 4)), np.zeros((240, 319, 4), np.uint8)),
    "wrong depth size": lambda seq: cv2.imwrite(str(_depth(seq, 4)), np.zeros((24, 32), np.uint16)),
    "float32 TIFF depth": lambda seq: _depth(seq, 4).write_bytes(
        cv2.imencode(".tiff", np.ones((240, 320), np.float32))[1].tobytes()),
    "8-bit depth frame": lambda seq: cv2.imwrite(str(_depth(seq, 4)), np.full((240, 320), 100, np.uint8)),
    "30000x30000 header": lambda seq: _rgb(seq, 4).write_bytes(_png_of_size(30000, 30000)),
    "missing file": lambda seq: _rgb(seq, 4).unlink(),
}


@pytest.mark.parametrize("case", list(SKIPPED_FRAME))
def test_a_bad_frame_is_skipped_and_counted(capsys, seq, tmp_path, case):
    SKIPPED_FRAME[case](seq)
    out = tmp_path / "run"
    rc, stdout, err = cli(capsys, *run_args(seq, out))
    assert rc == 0 and "Traceback" not in err, err
    s = stats_of(out)
    assert s["skipped_frames"] == 1 and s["frames"] == N - 1
    assert "1 skipped" in stdout
    assert (out / "map" / "map.json").is_file() and s["keyframes"] >= 1  # the map is kept


def test_huge_header_is_refused_before_decoding(tmp_path):
    from vslam.datasets.base import CorruptFrameError, image_header_size, load_image

    path = tmp_path / "bomb.png"
    path.write_bytes(_png_of_size(30000, 30000))
    assert image_header_size(path.read_bytes()) == (30000, 30000)
    with pytest.raises(CorruptFrameError, match="header says 30000x30000"):
        load_image(path)
    jpg = cv2.imencode(".jpg", np.zeros((48, 64), np.uint8))[1].tobytes()
    assert image_header_size(jpg) == (64, 48)


BAD_RUN = {
    "8-bit depth": (lambda seq: [cv2.imwrite(str(p), np.full((240, 320), 100, np.uint8))
                                 for p in (seq / "depth").iterdir()], [], "16-bit"),
    "first frame corrupt": (lambda seq: _rgb(seq, 0).write_bytes(b"xx"), [], "first frame"),
    "too many corrupt": (lambda seq: [_rgb(seq, i).write_bytes(b"xx") for i in (2, 5, 8)], [], "damaged"),
    "max_depth NaN": (None, ["--set", "frontend.max_depth=.nan"], "NaN"),
    "min above max depth": (None, ["--set", "frontend.min_depth=20"], "min_depth"),
    "negative max-frames": (None, ["--max-frames", "-1"], "--max-frames"),
    "zero max-frames": (None, ["--max-frames", "0"], "--max-frames"),
    "start beyond end": (None, ["--start-frame", "99"], "--start-frame"),
    "non-UTF-8 rgb.txt": (lambda seq: (seq / "rgb.txt").write_bytes((seq / "rgb.txt").read_bytes() + b"\xff\xfe\n"),
                          [], "rgb.txt:"),
    "non-UTF-8 camera.yaml": (lambda seq: (seq / "camera.yaml").write_bytes(b"fx: 50\n\xff: 1\n"), [],
                              "camera.yaml:2"),
    "non-UTF-8 depth.txt": (lambda seq: (seq / "depth.txt").write_bytes(b"\x80\n"), [], "depth.txt:1"),
    "non-numeric width": (lambda seq: (seq / "camera.yaml").write_text(
        "fx: 50\nfy: 51\ncx: 31.5\ncy: 23.5\nwidth: abc\nheight: 240\n"), [], "width"),
    "negative fx": (lambda seq: (seq / "camera.yaml").write_text(
        "fx: -1\nfy: 51\ncx: 31.5\ncy: 23.5\nwidth: 320\nheight: 240\n"), [], "positive"),
    "unknown setting": (None, ["--set", "frontend.nope=1"], "unknown setting"),
}


@pytest.mark.parametrize("case", list(BAD_RUN))
def test_bad_input_is_one_line(capsys, seq, tmp_path, case):
    mutate, extra, word = BAD_RUN[case]
    if mutate is not None:
        mutate(seq)
    out = tmp_path / "run"
    rc, _, err = cli(capsys, *run_args(seq, out, *extra))
    one_error(err, rc, 2, word)
    if (out / "trajectory.txt").exists():
        whole_lines(out / "trajectory.txt")
    if (out / "stats.json").exists():
        assert stats_of(out)["error"]


def test_non_utf8_trajectory_for_eval(capsys, tmp_path):
    good = tmp_path / "gt.txt"
    good.write_text("".join(f"{i} {0.1 * i} 0 0 0 0 0 1\n" for i in range(10)))
    bad = tmp_path / "est.txt"
    bad.write_bytes(good.read_bytes() + b"\xc3(\n")
    rc, _, err = cli(capsys, "eval", bad, good)
    one_error(err, rc, 2, "est.txt:11")


# ---------------------------------------------------------------------------------------- maps
@pytest.fixture(scope="module")
def saved_map(tmp_path_factory) -> Path:
    from tests.map._builders import random_map
    from vslam.geometry.camera import PinholeCamera
    from vslam.map.io import save_map

    root = tmp_path_factory.mktemp("map")
    save_map(random_map(1, mode="orb"), root, camera=PinholeCamera(500.0, 500.0, 320.0, 240.0, 640, 480))
    return root / "map"


def _manifest(root: Path, edit) -> None:
    m = json.loads((root / "map.json").read_text())
    edit(m)
    (root / "map.json").write_text(json.dumps(m))


def _kf_arrays(fn):
    def mutate(a):
        fn(a)
        return a
    return mutate


MAP_CASES = {
    "NaN keyframe pose": (lambda r: _rewrite(r, "keyframes.npz", _kf_arrays(
        lambda a: a["T_world_cam"].__setitem__((0, 0, 3), np.nan))), "pose is not a finite"),
    "non-rigid pose": (lambda r: _rewrite(r, "keyframes.npz", _kf_arrays(
        lambda a: a["T_world_cam"].__setitem__((0, 0, 0), 5.0))), "rigid"),
    "camera fx=-1": (lambda r: _manifest(r, lambda m: m["camera"].__setitem__("fx", -1)), "camera"),
    "camera width text": (lambda r: _manifest(r, lambda m: m["camera"].__setitem__("width", "abc")), "camera"),
    "camera width 0": (lambda r: _manifest(r, lambda m: m["camera"].__setitem__("width", 0)), "camera"),
    "camera unknown key": (lambda r: _manifest(r, lambda m: m["camera"].__setitem__("zoom", 2)), "camera"),
    "capacity 1e12": (lambda r: _manifest(r, lambda m: m["point_store"].__setitem__("capacity", 10**12)),
                      "capacity"),
    "negative rows": (lambda r: _manifest(r, lambda m: m["point_store"].__setitem__("rows", -5)), "point_store"),
    "edge to a missing keyframe": (lambda r: _rewrite(r, "covisibility.npz", _kf_arrays(
        lambda a: a["edges"].__setitem__((0, 1), 987654))), "not a graph node"),
    "graph node not a keyframe": (lambda r: _rewrite(r, "covisibility.npz", _kf_arrays(
        lambda a: a["nodes"].__setitem__(0, 987654))), "not"),
    "duplicate keyframe ids": (lambda r: _rewrite(r, "keyframes.npz", _kf_arrays(
        lambda a: a["id"].__setitem__(1, a["id"][0]))), "not unique"),
    "point id out of range": (lambda r: _rewrite(r, "keyframes.npz", _kf_arrays(
        lambda a: a["point_ids"].__setitem__(0, 10**9))), "point_ids"),
    "manifest not JSON": (lambda r: (r / "map.json").write_text("{"), "map.json"),
    "manifest a list": (lambda r: (r / "map.json").write_text("[]"), "map.json"),
}


def _rewrite(root: Path, file: str, mutate) -> None:
    from tests.map._builders import rewrite_npz

    rewrite_npz(root, file, mutate)


@pytest.mark.parametrize("case", list(MAP_CASES))
def test_hostile_map_is_refused(tmp_path, saved_map, case):
    from vslam.map.io import load_map

    root = Path(shutil.copytree(saved_map, tmp_path / "map"))
    mutate, word = MAP_CASES[case]
    mutate(root)
    with pytest.raises(MapFormatError) as info:
        load_map(root.parent)
    assert word in str(info.value) and str(root) in str(info.value)


def test_hostile_map_through_localize(capsys, tmp_path, saved_map, seq):
    root = Path(shutil.copytree(saved_map, tmp_path / "run" / "map"))
    _manifest(root, lambda m: m["point_store"].__setitem__("capacity", 10**12))
    rc, _, err = cli(capsys, "localize", root.parent, seq, "-o", tmp_path / "loc", "--no-progress")
    one_error(err, rc, 2, "capacity")


# ------------------------------------------------------------------------------------- reports
def _bench(tmp_path: Path, rows) -> Path:
    folder = tmp_path / "bench"
    folder.mkdir()
    (folder / "results.json").write_text(json.dumps({"rows": rows}))
    return folder


REPORT_CASES = {
    "rows [{}]": ([{}], "lacks 'name'"),
    "rows [1]": ([1], "rows[0]"),
    "name not text": ([{"name": 5, "repeat": 0}], "rows[0].name"),
    "repeat text": ([{"name": "a", "repeat": "x"}], "rows[0].repeat"),
    "output ../victim": ([{"name": "a", "repeat": 0, "output": "../victim"}], "leaves the bench folder"),
    "output absolute": ([{"name": "a", "repeat": 0, "output": "/tmp/victim"}], "leaves the bench folder"),
}


@pytest.mark.parametrize("case", list(REPORT_CASES))
def test_crafted_results_json(capsys, tmp_path, case):
    rows, word = REPORT_CASES[case]
    victim = tmp_path / "victim"
    victim.mkdir()
    (victim / "stats.json").write_text("{}")
    (victim / "report.html").write_text("mine")
    folder = _bench(tmp_path, rows)
    rc, _, err = cli(capsys, "report", folder, "-o", folder / "report.html")
    one_error(err, rc, 2, word)
    assert (victim / "report.html").read_text() == "mine"


STATS_CASES = {
    "loops: 5": {"frames": 3, "loops": 5},
    "loops: [5]": {"frames": 3, "loops": [5]},
    "frames text": {"frames": "three"},
    "stage_ms list": {"frames": 3, "stage_ms": [1, 2]},
    "stage_ms text value": {"frames": 3, "stage_ms": {"track": "slow"}},
    "a list": [1, 2],
    "path number": {"frames": 3, "path": 7},
}


@pytest.mark.parametrize("case", list(STATS_CASES))
def test_crafted_stats_json(capsys, tmp_path, case):
    run = tmp_path / "run"
    run.mkdir()
    (run / "stats.json").write_text(json.dumps(STATS_CASES[case]))
    rc, _, err = cli(capsys, "report", run, "-o", tmp_path / "r.html")
    one_error(err, rc, 2, "stats.json")
    assert not (tmp_path / "r.html").exists()


@pytest.mark.parametrize("header", ["element vertex abc", "element vertex -5", "element vertex"])
def test_bad_ply_header(tmp_path, header):
    from vslam.reconstruction.ply import read_ply
    from vslam.report.ply import read_ply_points as read_points

    path = tmp_path / "sparse.ply"
    path.write_bytes(f"ply\nformat ascii 1.0\n{header}\nproperty float x\nproperty float y\nproperty float z\n"
                     "end_header\n1 2 3\n".encode())
    for reader in (read_ply, read_points):
        with pytest.raises(MapFormatError, match="sparse.ply"):
            reader(path)


def test_report_output_that_is_a_folder(capsys, tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    (run / "stats.json").write_text(json.dumps({"frames": 0}))
    rc, _, err = cli(capsys, "report", run, "-o", tmp_path)
    one_error(err, rc, 2, "is a folder")


def test_inside_refuses_escapes(tmp_path):
    assert inside(tmp_path, "runs/a/0") == (tmp_path / "runs/a/0").resolve()
    for bad in ("../x", "/etc", "a/../../x"):
        with pytest.raises(VslamError, match="outside"):
            inside(tmp_path, bad)


# ------------------------------------------------------------------------------------ geometry
@pytest.mark.parametrize("threshold", [1e-9, 1e-6])
def test_ransac_without_inliers_is_a_geometry_error(threshold):
    from vslam.geometry.align import align_points

    rng = np.random.default_rng(0)
    src, dst = rng.normal(size=(60, 3)), rng.normal(size=(60, 3)) * 100
    with pytest.raises(GeometryError, match="inliers"):
        align_points(src, dst, threshold=threshold)


def test_ransac_iteration_count_is_finite():
    from vslam.geometry.align import _ransac_iterations

    assert _ransac_iterations(0.0, 0.999, 1000) == 1000
    assert _ransac_iterations(1.0, 0.999, 1000) == 1
    assert _ransac_iterations(0.5, 0.999, 1000) == 52  # log(0.001) / log(1 - 0.125) = 51.7
    assert _ransac_iterations(1e-6, 0.999, 1000) == 1000


# ----------------------------------------------------------------------------- other text inputs
def _non_utf8(path: Path, good: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(good.encode() + b"\n# caf\xe9\n")
    return path


TEXT_CASES = {
    "--config": lambda tmp, seq: (["run", seq, "-o", tmp / "run", "--no-progress", "--config",
                                   _non_utf8(tmp / "c.yaml", "frontend: {}")], "c.yaml:2"),
    "bench spec": lambda tmp, seq: (["bench", _non_utf8(tmp / "spec.yaml", "runs: []"), "-o", tmp / "b"],
                                    "spec.yaml:2"),
    "results.json": lambda tmp, seq: (["report", _non_utf8(tmp / "b" / "results.json", '{"rows": []}').parent,
                                       "-o", tmp / "r.html"], "results.json:2"),
    "stats.json": lambda tmp, seq: (["report", _non_utf8(tmp / "run" / "stats.json", '{"frames": 1}').parent,
                                     "-o", tmp / "r.html"], "stats.json:2"),
    "groundtruth.txt": lambda tmp, seq: (["eval", _non_utf8(tmp / "g.txt", "1 0 0 0 0 0 0 1"),
                                          _non_utf8(tmp / "e.txt", "1 0 0 0 0 0 0 1")], "e.txt:2"),
}


@pytest.mark.parametrize("case", list(TEXT_CASES))
def test_non_utf8_text_input(capsys, tmp_path, base_seq, case):
    argv, word = TEXT_CASES[case](tmp_path, base_seq)
    rc, _, err = cli(capsys, *argv)
    one_error(err, rc, 2, word, "not UTF-8")


def test_npz_header_claiming_a_huge_shape_is_refused_before_allocating(tmp_path, saved_map):
    """A ``.npy`` header inside the map's zip patched to claim 10^12 rows (checksums fixed)."""
    import hashlib
    import re
    import zipfile

    from vslam.map.io import load_map

    root = Path(shutil.copytree(saved_map, tmp_path / "map"))
    with zipfile.ZipFile(root / "covisibility.npz") as zf:
        members = {n: bytearray(zf.read(n)) for n in zf.namelist()}
    npy = members["edges.npy"]
    m = re.search(rb"'shape': \((\d+), 3\), \}( +)\n", npy)  # the header is padded with spaces
    grow = 12 - len(m.group(1))
    npy[m.start(1):m.end(2)] = b"9" * 12 + b", 3), }" + b" " * (len(m.group(2)) - grow)
    with zipfile.ZipFile(root / "covisibility.npz", "w") as zf:  # stored, with valid CRCs
        for n, b in members.items():
            zf.writestr(n, bytes(b))
    data = (root / "covisibility.npz").read_bytes()
    _manifest(root, lambda mm: mm["files"]["covisibility.npz"].update(
        bytes=len(data), sha256=hashlib.sha256(bytes(data)).hexdigest()))
    with pytest.raises(MapFormatError, match=r"claims shape \(999999999999, 3\)"):
        load_map(root.parent)


# ------------------------------------------------------------------------------------ localize
@pytest.fixture(scope="module")
def mapped(tmp_path_factory, base_seq) -> Path:
    from vslam.api import run_path

    out = tmp_path_factory.mktemp("mapped") / "run"
    run_path(base_seq, out, sensor="rgbd")
    return out


def test_localize_into_the_map_folder_is_refused(capsys, mapped, base_seq):
    before = (mapped / "trajectory.txt").read_bytes()
    rc, _, err = cli(capsys, "localize", mapped, base_seq, "-o", mapped, "--no-progress")
    one_error(err, rc, 2, "is the input")
    assert (mapped / "trajectory.txt").read_bytes() == before


def test_localize_in_another_scene_counts_frames_not_localized(capsys, mapped, tmp_path):
    """Random textures share no structure with the map: each frame is counted as not localized
    (a RANSAC without inliers raised OverflowError here before, see the geometry cases below)."""
    from tests.datasets.conftest import write_tum

    other = write_tum(tmp_path / "other", n=6, size=(320, 240), camera_yaml="fx: 262.5\nfy: 262.5\ncx: 159.5\n"
                      "cy: 119.5\nwidth: 320\nheight: 240\n")
    rc, out, err = cli(capsys, "localize", mapped, other, "-o", tmp_path / "loc", "--no-progress")
    assert rc == 0 and "Traceback" not in err, err
    s = stats_of(tmp_path / "loc")
    assert s["frames"] == 6 and s["localized"] == 0 and "error" not in s
