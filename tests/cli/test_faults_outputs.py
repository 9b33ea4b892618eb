"""Fault injection, round 2 (issue #27): no command writes over one of its inputs, every command
writes atomically (a full disk keeps the previous file), a rerun never costs the last complete run,
calibration numbers are checked where they enter, decimal commas in ``rgb.txt`` are named.

As in ``test_faults.py``: each case asserts the exit status, a single ``vslam ...`` error line that
names the file (and key), and what is left on disk.
"""
from __future__ import annotations

import errno
import json
import os
import shutil
import signal
from pathlib import Path

import cv2
import numpy as np
import pytest

import vslam.outputs
from tests.cli.test_faults import _rgb, _start_slow, base_seq, cli, one_error, run_args, seq, stats_of  # noqa: F401

TRAJ = "".join(f"{i} {np.cos(i / 3):.6f} {np.sin(i / 3):.6f} {0.1 * i} 0 0 0 1\n" for i in range(10))


def _snapshot(*paths: Path) -> dict:
    """Every file under ``paths`` with its bytes."""
    out = {}
    for p in paths:
        for f in ([p] if p.is_file() else sorted(q for q in p.rglob("*") if q.is_file())):
            out[str(f)] = f.read_bytes()
    return out


# ------------------------------------------------------------------------- outputs onto inputs
def _traj_pair(tmp: Path) -> tuple[Path, Path]:
    (tmp / "gt.txt").write_text(TRAJ)
    (tmp / "est.txt").write_text(TRAJ)
    return tmp / "gt.txt", tmp / "est.txt"


def _eval_json_onto_ref(tmp, seq):
    gt, est = _traj_pair(tmp)
    return ["eval", gt, est, "--json", gt], gt, [gt, est]


def _eval_plot_onto_est_by_link(tmp, seq):
    gt, est = _traj_pair(tmp)
    (tmp / "link.png").symlink_to(est)
    return ["eval", gt, est, "--plot", tmp / "link.png"], tmp / "link.png", [gt, est]


def _report_onto_stats(tmp, seq):
    run = tmp / "run"
    run.mkdir()
    (run / "stats.json").write_text(json.dumps({"frames": 1}))
    return ["report", run, "-o", run / "stats.json"], run / "stats.json", [run]


def _merge_onto_b(tmp, seq):
    for name in ("a", "b"):
        (tmp / name / "map").mkdir(parents=True)
        (tmp / name / "keyframes.txt").write_text(TRAJ)
    return ["merge", tmp / "a", tmp / "b", "-o", tmp / "b"], tmp / "b", [tmp / "a", tmp / "b"]


def _calibrate_onto_image(tmp, seq):
    return (["calibrate", seq / "rgb", "--board", "9x6", "--square", "0.03", "-o", _rgb(seq, 2)], _rgb(seq, 2),
            [seq / "rgb"])


def _vocab_train_onto_image(tmp, seq):
    return ["vocab", "train", seq, "-o", _rgb(seq, 0), "--no-progress"], _rgb(seq, 0), [seq]


def _vocab_convert_onto_input(tmp, seq):
    voc = tmp / "voc.txt"
    voc.write_text("10 2 0 0\n")
    return ["vocab", "convert", voc, voc], voc, [voc]


ONTO_INPUT = {
    "eval --json REF": _eval_json_onto_ref,
    "eval --plot EST (a link to it)": _eval_plot_onto_est_by_link,
    "report -o RUN/stats.json": _report_onto_stats,
    "merge A B -o B": _merge_onto_b,
    "calibrate -o one of its images": _calibrate_onto_image,
    "vocab train -o one of its images": _vocab_train_onto_image,
    "vocab convert IN IN": _vocab_convert_onto_input,
}


@pytest.mark.parametrize("case", list(ONTO_INPUT))
def test_no_command_writes_over_its_input(capsys, seq, tmp_path, case):
    argv, target, inputs = ONTO_INPUT[case](tmp_path, seq)
    before = _snapshot(*inputs)
    rc, out, err = cli(capsys, *argv)
    one_error(err, rc, 2, str(target))
    assert _snapshot(*inputs) == before  # every input byte for byte
    assert not [p for p in tmp_path.rglob("*") if ".tmp-" in p.name]


def test_report_into_its_run_folder_is_allowed(capsys, tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    (run / "stats.json").write_text(json.dumps({"frames": 0}))
    rc, _, err = cli(capsys, "report", run, "-o", run / "report.html")
    assert rc == 0, err
    assert json.loads((run / "stats.json").read_text()) == {"frames": 0}


# ---------------------------------------------------------------------------------- full disk
def _full_disk_for(monkeypatch, target: Path, err_no: int = errno.ENOSPC) -> None:
    """Writes to ``target``'s temporary sibling put half their bytes on disk, then fail with ``err_no``
    (the first write is short, the next raises), as a disk that fills up midway would."""
    real = vslam.outputs._raw_write
    prefix = f".{target.name}.tmp-"

    def write(fd, data):
        if not os.path.basename(os.readlink(f"/proc/self/fd/{fd}")).startswith(prefix):
            return real(fd, data)
        if os.fstat(fd).st_size == 0 and len(data) > 1:
            return real(fd, bytes(data[: len(data) // 2]))
        raise OSError(err_no, os.strerror(err_no))

    monkeypatch.setattr(vslam.outputs, "_raw_write", write)


def _calibration_views(tmp: Path) -> Path:
    from tests.test_calibrate import _render
    from vslam.calibrate import Board

    folder = tmp / "views"
    folder.mkdir()
    for name, img in _render(Board(9, 6, 0.03), 8, seed=2):
        cv2.imwrite(str(folder / f"{name}.png"), img)
    return folder


def _bench_spec(tmp: Path) -> Path:
    spec = tmp / "spec.yaml"
    spec.write_text("runs:\n  - {name: r1, data: somewhere}\n")
    (tmp / "somewhere").mkdir(exist_ok=True)
    return spec


FULL_DISK = {  # name: (argv from (tmp, seq), the file it writes)
    "eval --json": (lambda tmp, seq: ["eval", *_traj_pair(tmp), "--json", tmp / "ate.json"], "ate.json"),
    "eval --plot": (lambda tmp, seq: ["eval", *_traj_pair(tmp), "--plot", tmp / "ate.png"], "ate.png"),
    "calibrate -o": (lambda tmp, seq: ["calibrate", _calibration_views(tmp), "--board", "9x6", "--square", "0.03",
                                       "-o", tmp / "camera.yaml"], "camera.yaml"),
    "vocab train -o": (lambda tmp, seq: ["vocab", "train", seq / "rgb", "-o", tmp / "voc.npz", "--k", "3", "-L", "2",
                                         "--every", "1", "--features", "200", "--no-progress"], "voc.npz"),
    "vocab convert": (lambda tmp, seq: ["vocab", "convert", vslam.loop.vocabulary.DEFAULT_VOCABULARY_PATH,
                                        tmp / "ORBvoc.txt"], "ORBvoc.txt"),
    "bench results.json": (lambda tmp, seq: ["bench", _bench_spec(tmp), "-o", tmp / "b", "--dry-run", "--workers",
                                             "0", "--no-plots"], "b/results.json"),
    "report -o": (lambda tmp, seq: ["report", _report_run(tmp), "-o", tmp / "report.html"], "report.html"),
}


def _report_run(tmp: Path) -> Path:
    run = tmp / "run"
    run.mkdir()
    (run / "stats.json").write_text(json.dumps({"frames": 0}))
    return run


@pytest.mark.parametrize("case", list(FULL_DISK))
def test_full_disk_keeps_the_previous_file(capsys, seq, tmp_path, monkeypatch, case):
    import vslam.loop.vocabulary  # noqa: F401  (the packaged vocabulary's path)

    make, name = FULL_DISK[case]
    argv = make(tmp_path, seq)
    target = tmp_path / name
    target.parent.mkdir(exist_ok=True)
    target.write_bytes(b"the previous good file\n")
    _full_disk_for(monkeypatch, target)
    rc, _, err = cli(capsys, *argv)
    line = one_error(err, rc, 2, str(target), "No space left on device", "free space")
    assert ".tmp-" not in line  # the target named, not the temporary file
    assert target.read_bytes() == b"the previous good file\n"
    assert not [p for p in tmp_path.rglob("*") if ".tmp-" in p.name]


@pytest.mark.parametrize("err_no,words", [(errno.EROFS, "read-only"), (errno.EACCES, "writable")])
def test_write_errors_say_what_is_wrong(capsys, tmp_path, monkeypatch, err_no, words):
    target = tmp_path / "ate.json"
    _full_disk_for(monkeypatch, target, err_no)
    rc, _, err = cli(capsys, "eval", *_traj_pair(tmp_path), "--json", target)
    line = one_error(err, rc, 2, str(target), words)
    assert "free space" not in line and ".tmp-" not in line and not target.exists()


def test_a_name_too_long_is_named_as_such(capsys, tmp_path):
    target = tmp_path / ("x" * 300 + ".json")
    rc, out, err = cli(capsys, "eval", *_traj_pair(tmp_path), "--json", target)
    line = one_error(err, rc, 2, str(target), "too long")
    assert "free space" not in line and out == ""


# ------------------------------------------------------------------------------------- reruns
def test_a_stopped_then_failed_rerun_keeps_the_last_complete_run(capsys, seq, tmp_path):
    out = tmp_path / "run"
    rc, _, err = cli(capsys, *run_args(seq, out, "--trajectory-format", "kitti"))
    assert rc == 0, err
    names = ("map", "keyframes.txt", "sparse.ply", "stats.json", "trajectory.txt", "trajectory_kitti.txt",
             "trajectory_kitti_times.txt", "config.yaml", "topology.json")
    good = {n: _snapshot(out / n) for n in names}
    proc = _start_slow(seq, out)  # a rerun stopped by SIGTERM
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    one_error(err, proc.returncode, 143, "terminated")
    _rgb(seq, 0).write_bytes(b"xx")  # a rerun that fails on bad input
    rc, _, err = cli(capsys, *run_args(seq, out))
    one_error(err, rc, 2, "first frame")
    prev = out / ".previous-run"
    for n in names:  # the complete run, whole, beside the failed one
        assert _snapshot(prev / n) == {k.replace(str(out), str(prev)): v for k, v in good[n].items()}, n
    assert "error" not in stats_of(prev) and "error" in stats_of(out)
    assert not (out / "trajectory_kitti.txt").exists()  # moved aside too: old and new never mix
    shutil.copy(tmp_path / "seq" / "rgb" / _rgb(seq, 1).name, _rgb(seq, 0))  # fixed: the next run completes
    rc, _, err = cli(capsys, *run_args(seq, out))
    assert rc == 0, err
    assert not prev.exists() and "error" not in stats_of(out)


# ---------------------------------------------------------------------------------- calibration
CAMERA = "fx: 262.5\nfy: 262.5\ncx: 159.5\ncy: 119.5\nwidth: 320\nheight: 240\n"
KALIBR = ("cam0:\n  camera_model: pinhole\n  intrinsics: [262.5, {fy}, 159.5, 119.5]\n  distortion_model: radtan\n"
          "  distortion_coeffs: {dist}\n  resolution: [320, 240]\n")


def _camera(text: str):
    return lambda seq: (seq / "camera.yaml").write_text(text)


def _camera_key(key: str, value: str):
    return _camera("".join(f"{k}: {value if k == key else v}\n" for k, v in
                           (ln.split(": ") for ln in CAMERA.splitlines())))


BAD_CALIBRATION = {  # name: (mutate the sequence, extra run arguments, words of the error line)
    "fx: yes": (_camera_key("fx", "yes"), [], ("camera.yaml", "'fx'", "YAML boolean")),
    "fx as text": (_camera_key("fx", '"262.5"'), [], ("camera.yaml", "'fx'", "not a number")),
    "fx 1e-300": (_camera_key("fx", "1e-300"), [], ("camera.yaml", "'fx'", "implausible")),
    "fy 1e9": (_camera_key("fy", "1e9"), [], ("camera.yaml", "'fy'", "implausible")),
    "principal point outside": (_camera_key("cx", "-5000"), [], ("camera.yaml", "'cx'", "inside")),
    "cy beyond the image": (_camera_key("cy", "99999"), [], ("camera.yaml", "'cy'", "inside")),
    "distortion NaN": (_camera(CAMERA + "dist: [.nan, 0, 0, 0, 0]\n"), [], ("camera.yaml", "'dist'", "finite")),
    "distortion 1e12": (_camera(CAMERA + "dist: [1e6, -1e9, 0, 0, 1e12]\n"), [], ("camera.yaml", "distortion[0]")),
    "depth_scale 1e-300": (_camera(CAMERA + "depth_scale: 1e-300\n"), [], ("camera.yaml", "'depth_scale'")),
    "depth_scale 1e300": (_camera(CAMERA + "depth_scale: 1e300\n"), [], ("camera.yaml", "'depth_scale'")),
    "width 320.5": (_camera_key("width", "320.5"), [], ("camera.yaml", "'width'", "whole number")),
    "over 1 MB": (_camera(CAMERA + "#" * 1_100_000 + "\n"), [], ("camera.yaml", "bytes")),
    "YAML alias bomb": (_camera("a: &a [x, x, x, x, x, x, x, x, x]\nb: &b [*a, *a, *a, *a, *a, *a, *a, *a]\n"
                                "c: [*b, *b, *b, *b, *b, *b, *b, *b]\n" + CAMERA), [], ("camera.yaml:2", "alias")),
    "Kalibr fy .inf": (lambda seq: (seq / "camchain.yaml").write_text(KALIBR.format(fy=".inf", dist="[0, 0, 0, 0]")),
                       ["--camera", "SEQ/camchain.yaml"], ("camchain.yaml", "cam0/intrinsics", "finite")),
    "Kalibr dist NaN": (lambda seq: (seq / "camchain.yaml").write_text(KALIBR.format(fy="262.5",
                                                                                     dist="[.nan, 0, 0, 0]")),
                        ["--camera", "SEQ/camchain.yaml"], ("camchain.yaml", "distortion_coeffs", "finite")),
    "OpenCV XML cut off": (lambda seq: (seq / "cam.xml").write_text(
        '<?xml version="1.0"?>\n<opencv_storage>\n<image_width>320</image_width>\n<camera_matrix type_id="opencv-'
        'matrix">\n  <rows>3</rows>\n  <data>\n    262.5 0. 159.5 0. 262.'), ["--camera", "SEQ/cam.xml"],
        ("cam.xml", "cannot parse")),
    "ORB-SLAM2 DepthMapFactor 0": (_camera("Camera.fx: 262.5\nCamera.fy: 262.5\nCamera.cx: 159.5\nCamera.cy: 119.5\n"
                                           "Camera.width: 320\nCamera.height: 240\nDepthMapFactor: 0\n"), [],
                                   ("camera.yaml", "depth_scale")),
}


def _comma_rgb(seq: Path) -> str:
    """rgb.txt with its timestamps written with decimal commas (file names untouched)."""
    lines = []
    for ln in (seq / "rgb.txt").read_text().splitlines():
        if ln.startswith("#"):
            lines.append(ln)
            continue
        t, rest = ln.split(maxsplit=1)
        lines.append(f"{t.replace('.', ',')} {rest}")
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize("case", list(BAD_CALIBRATION))
def test_calibration_numbers_are_checked_where_they_enter(capsys, seq, tmp_path, case):
    mutate, extra, words = BAD_CALIBRATION[case]
    mutate(seq)
    extra = [str(a).replace("SEQ", str(seq)) for a in extra]
    out = tmp_path / "run"
    rc, _, err = cli(capsys, *run_args(seq, out, *extra))
    one_error(err, rc, 2, *words)
    assert not (out / "trajectory.txt").exists() or "error" in stats_of(out)


@pytest.mark.shared
def test_every_real_calibration_still_loads(shared_data):
    from vslam.datasets.calibration import read_camera_file
    from vslam.datasets.detect import open_dataset

    data = shared_data
    files = [data / "tum_fr3_cabinet_keyframes58" / "TUM3.yaml", *sorted(data.glob("euroc*/mav0/cam*/sensor.yaml"))]
    for f in files:
        assert read_camera_file(f, (640, 480)).camera.fx > 400, f
    for seq_dir in ("tum_fr3_cabinet_keyframes58", "tum_rgbd_freiburg1_desk_9frames", "kitti_odometry/sequences/07",
                    "7scenes_redkitchen", "euroc_mh01_vi_80"):
        assert open_dataset(data / seq_dir).camera.fx > 400, seq_dir


def test_decimal_commas_in_rgb_txt_are_named(capsys, seq, tmp_path):
    (seq / "rgb.txt").write_text(_comma_rgb(seq))
    rc, _, err = cli(capsys, *run_args(seq, tmp_path / "run"))
    line = one_error(err, rc, 2, "rgb.txt:", "decimal comma")
    assert "duplicate" not in line


def test_an_error_on_the_temporary_file_names_the_target():
    from vslam.outputs import describe_os_error

    tmp = "/data/.ate.json.tmp-0123abcd.json"
    for err_no, words in ((errno.EROFS, "read-only"), (errno.ENAMETOOLONG, "too long"), (errno.ENOSPC, "free space")):
        line = describe_os_error(OSError(err_no, os.strerror(err_no), tmp), "/data/ate.json")
        assert line.startswith("/data/ate.json: cannot write") and words in line and ".tmp-" not in line
        assert ("free space" in line) == (err_no == errno.ENOSPC)


def test_merging_a_map_with_itself_is_refused(capsys, tmp_path):
    (tmp_path / "a" / "map").mkdir(parents=True)
    (tmp_path / "link").symlink_to(tmp_path / "a")
    rc, _, err = cli(capsys, "merge", tmp_path / "a", tmp_path / "link", "-o", tmp_path / "out")
    one_error(err, rc, 2, "same map")
    assert not (tmp_path / "out").exists()


# ------------------------------------------------------------------------------ maps (meaning)
def _db_file(header, kf_ids=(0,), words=(3,)):
    """A ``write_db(path, map)`` that writes a keyframe database file with this header and entries."""
    def write(path: Path, slam_map) -> Path:
        n = len(kf_ids)
        np.savez(path, header=np.array(header if isinstance(header, str) else json.dumps(header)),
                 kf_ids=np.array(kf_ids, np.int64), indptr=np.arange(n + 1, dtype=np.int64) * len(words) // max(n, 1),
                 words=np.array(list(words) * n, np.int32), values=np.ones(len(words) * n))
        return path
    return write


DB_HEADER = {"format": "vslam-keyframe-database", "version": 1, "n_words": 100}
HOSTILE_DATABASE = {  # name: (write the database file, words of the error)
    "header a JSON list": (_db_file("[]"), "not a JSON object"),
    "10^12 words announced": (_db_file({**DB_HEADER, "n_words": 10**12}), "n_words"),
    "word id beyond the vocabulary": (_db_file(DB_HEADER, words=(100,)), "out of range"),
    "ids of no keyframe": (_db_file(DB_HEADER, kf_ids=(987654,)), "not keyframes of the map"),
}


@pytest.mark.parametrize("case", list(HOSTILE_DATABASE))
def test_a_database_that_does_not_fit_its_map_is_refused(tmp_path, monkeypatch, case):
    from tests.map._builders import random_map
    from vslam.errors import MapFormatError
    from vslam.map.database import KeyframeDatabase
    from vslam.map.io import load_map, save_map

    write_db, words = HOSTILE_DATABASE[case]
    slam_map = random_map(1, mode="orb")
    monkeypatch.setattr(KeyframeDatabase, "save", lambda self, path: write_db(Path(path), slam_map))
    save_map(slam_map, tmp_path, database=KeyframeDatabase(100))  # checksums made consistent
    monkeypatch.undo()
    with pytest.raises(MapFormatError) as info:
        load_map(tmp_path)
    assert "database.npz" in str(info.value) and words in str(info.value)


def test_a_manifest_nested_deeply_is_refused(tmp_path):
    from vslam.errors import MapFormatError
    from vslam.map.io import load_map

    (tmp_path / "map").mkdir()
    (tmp_path / "map" / "map.json").write_text("[" * 200_000 + "]" * 200_000)
    with pytest.raises(MapFormatError, match="map.json: nested too deeply"):
        load_map(tmp_path)


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs /dev/full (Linux)")
def test_a_full_standard_output_is_named_as_such():
    """`vslam config > /dev/full`: one line that names the standard output, not "free space on the
    disk or choose another output folder" (no output folder is involved)."""
    import subprocess
    import sys

    with open("/dev/full", "w") as full:
        p = subprocess.run([sys.executable, "-c", "import sys; from vslam.cli import main; sys.exit(main(['config']))"],
                           stdout=full, stderr=subprocess.PIPE,
                           text=True, timeout=120)
    lines = p.stderr.strip().splitlines()
    assert p.returncode == 1 and len(lines) == 1, p.stderr
    assert "standard output" in lines[0] and "output folder" not in lines[0] and "Traceback" not in p.stderr
