"""The optional ORB-SLAM3 baseline: setup errors, settings, the child's tracking loop (with a stand-in
wheel), the subprocess protocol (with a stand-in "baseline python"), the comparison table, and,
when a baseline interpreter and vocabulary are configured, one short real run."""
from __future__ import annotations

import json
import os
import stat
import sys
import types
from pathlib import Path

import numpy as np

import pytest

from vslam.bench import orbslam3_baseline as orb
from vslam.bench.harness import LocalExecutor, run_benchmark
from vslam.bench.results import baseline_comparison, results_markdown, summarize
from vslam.bench.spec import parse_spec
from vslam.errors import VslamError
from vslam.geometry.camera import PinholeCamera


def test_needs_a_vocabulary(tmp_path, monkeypatch):
    monkeypatch.delenv(orb.VOCAB_ENV, raising=False)
    with pytest.raises(VslamError, match="--vocabulary FILE"):
        orb.check_vocabulary(None)
    with pytest.raises(VslamError, match="vocabulary not found"):
        orb.check_vocabulary(tmp_path / "ORBvoc.txt")


def test_missing_interpreter_is_a_clear_error(tmp_path, monkeypatch):
    monkeypatch.delenv(orb.PYTHON_ENV, raising=False)
    monkeypatch.setattr(orb.importlib.util, "find_spec", lambda name: None)
    with pytest.raises(VslamError, match=r"--baseline-python .*VSLAM_ORBSLAM3_PYTHON"):
        orb.resolve_python(None)
    with pytest.raises(VslamError, match="not an executable Python"):
        orb.resolve_python(tmp_path / "nope" / "python")
    monkeypatch.setenv(orb.PYTHON_ENV, sys.executable)
    assert orb.resolve_python(None) == sys.executable


def test_interpreter_without_the_wheel_is_rejected(tmp_path):
    """This test's interpreter (vslam's venv, which must not hold pyorbslam3) fails the import check."""
    if orb.importlib.util.find_spec("pyorbslam3") is not None:
        pytest.skip("pyorbslam3 is installed in this interpreter")
    voc = tmp_path / "ORBvoc.txt"
    voc.write_text("10 4 0 0\n")
    with pytest.raises(VslamError, match=r"cannot run the ORB-SLAM3 baseline .*pyorbslam3.*pip install pyorbslam3"):
        orb.make_runner(voc, python=sys.executable)


def test_settings_use_the_old_keys_and_viewer_block():
    cam = PinholeCamera(fx=707.0912, fy=707.0912, cx=601.8873, cy=183.1104, width=1226, height=370, baseline=0.53716)
    text = orb.settings_yaml(cam, "stereo", 10.0)
    assert text.startswith("%YAML:1.0")
    assert "Camera.fx: 707.0912" in text and "Camera.width: 1226" in text and "Camera.fps: 10" in text
    assert f"Camera.bf: {707.0912 * 0.53716}" in text
    assert "ORBextractor.nFeatures: 2000" in text  # KITTI-sized image
    assert "Viewer.ViewpointF" in text and "Rectified" not in text


def test_euroc_ns_trajectory_is_read_in_seconds(tmp_path):
    f = tmp_path / "t.txt"
    f.write_text("1305031453359684000.000000 1.0 2.0 3.0 0 0 0.7071067811865476 0.7071067811865476\n"
                 "1305031453391690000.000000 1.5 2.0 3.0 0 0 0 1\n"
                 "1305031453391690000.000000 1.5 2.0 3.0 0 0 0 1\n")  # a lost frame: ORB-SLAM3 repeats the last
    traj = orb.read_euroc_ns(f)
    assert np.allclose(traj.timestamps, [1305031453.359684, 1305031453.391690])
    assert np.allclose(traj.T_world_cam[0][:3, 3], [1, 2, 3])
    assert np.allclose(traj.T_world_cam[0][:3, :3], [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-9)
    (tmp_path / "empty.txt").write_text("")
    assert orb.read_euroc_ns(tmp_path / "empty.txt") is None


def _fake_wheel(gt_by_time, created, lose=3, final_file=True):
    """A stand-in ``pyorbslam3``: tracking returns the ground-truth pose, frame ``lose`` is lost;
    ``save_trajectory_euroc`` writes the ground truth of every frame in EuRoC ns format."""

    class FakeSlam:
        def __init__(self, vocab, settings, sensor, use_viewer=False):
            created.append((vocab, settings, sensor, use_viewer))
            self.n = 0
            self.seen = []

        def track_rgbd(self, image, depth, t):
            assert depth.dtype == np.float32 and image.shape[:2] == depth.shape
            self.n += 1
            self.seen.append(t)
            valid = self.n != lose
            return types.SimpleNamespace(pose_valid=valid, pose_wc=gt_by_time[t] if valid else None)

        def save_trajectory_euroc(self, filename):
            from scipy.spatial.transform import Rotation

            with open(filename, "w") as f:
                for t in self.seen if final_file else []:
                    T = gt_by_time[t]
                    q = Rotation.from_matrix(T[:3, :3]).as_quat()
                    f.write(f"{1e9 * t:.6f} {T[0, 3]} {T[1, 3]} {T[2, 3]} {q[0]} {q[1]} {q[2]} {q[3]}\n")

        def shutdown(self):
            created.append("shutdown")

    return types.SimpleNamespace(Slam=FakeSlam, Sensor=types.SimpleNamespace(MONOCULAR=0, STEREO=1, RGBD=2))


@pytest.mark.parametrize("final_file", [True, False])
def test_child_tracking_loop_with_a_stand_in_wheel(tmp_path, monkeypatch, shared_data, final_file):
    """track_sequence with a fake wheel: the final (EuRoC) trajectory is used when written, else the
    online poses (lost frame dropped); settings and stats files are written."""
    from vslam.datasets import open_dataset
    from vslam.trajectory import read_trajectory

    seq = shared_data / "tum_rgbd_freiburg1_desk_9frames"
    gt = open_dataset(seq, sensor="rgbd").ground_truth()
    gt_by_time = dict(zip(gt.timestamps.tolist(), gt.T_world_cam))
    created: list = []
    monkeypatch.setattr(orb, "_import_pyorbslam3", lambda: _fake_wheel(gt_by_time, created, final_file=final_file))
    out = tmp_path / "run"
    stats = orb.track_sequence(seq, out, tmp_path / "voc.txt", sensor="rgbd", pace="none")
    assert created[0][2] == 2 and created[0][3] is False and created[-1] == "shutdown"
    assert stats["frames"] == 9 and stats["tracked_online"] == 8 and stats["paced"] is False
    assert stats["tracked"] == (9 if final_file else 8) and stats["lost"] == 9 - stats["tracked"]
    assert stats["trajectory"] == ("final" if final_file else "online")
    traj = read_trajectory(out / "trajectory.txt")
    assert len(traj) == (9 if final_file else 8)
    matched = np.array([gt_by_time[min(gt_by_time, key=lambda t: abs(t - s))] for s in traj.timestamps])
    assert np.abs(traj.T_world_cam - matched).max() < 1e-5
    assert json.loads((out / "orbslam3_stats.json").read_text())["tracked_online"] == 8
    assert "DepthMapFactor: 1.0" in (out / "orbslam3_settings.yaml").read_text()


FAKE_CHILD = '''#!{python}
"""A stand-in baseline interpreter: answers the import check, and for a run writes the ground truth
of the sequence (every other pose moved +-1 cm in x) as trajectory.txt plus orbslam3_stats.json, like the child."""
import json, sys
from pathlib import Path
if sys.argv[1:2] == ["-c"]:
    sys.exit({check_rc})
args = dict(zip(sys.argv[3::2], sys.argv[4::2]))  # after "-m vslam.bench.orbslam3_baseline"
assert sys.argv[1:3] == ["-m", "vslam.bench.orbslam3_baseline"], sys.argv
from vslam.datasets import open_dataset
from vslam.trajectory import write_tum
if {crash}:
    import os, signal
    os.kill(os.getpid(), signal.SIGSEGV)
out = Path(args["--output"])
ds = open_dataset(args["--data"], sensor=args.get("--sensor"))
gt = ds.ground_truth()
gt.T_world_cam[0::2, 0, 3] += 0.01
gt.T_world_cam[1::2, 0, 3] -= 0.01
write_tum(out / "trajectory.txt", gt)
(out / "orbslam3_stats.json").write_text(json.dumps(dict(
    frames=len(ds), tracked=len(gt), lost=0, wall_s=1.0, fps=float(len(ds)), sensor=args.get("--sensor"),
    system="orbslam3", paced=args["--pace"] == "all", pace=args["--pace"], vocabulary=args["--vocabulary"])))
print("fake orbslam3 done")
'''


def _write_fake_python(path: Path, check_rc: int = 0, crash: bool = False) -> Path:
    path.write_text(FAKE_CHILD.format(python=sys.executable, check_rc=check_rc, crash=crash))
    path.chmod(path.stat().st_mode | stat.S_IXUSR)
    return path


def test_subprocess_protocol_with_a_stand_in_interpreter(tmp_path, shared_data):
    """vslam bench's baseline path end to end through a fake "baseline python": the child's
    trajectory is evaluated by the parent (ATE ~ the +-1 cm noise), and results.md pairs the runs."""
    seq = shared_data / "tum_rgbd_freiburg1_desk_9frames"
    py = _write_fake_python(tmp_path / "python")
    voc = tmp_path / "ORBvoc.txt"
    voc.write_text("10 5 0 0\n")
    runner = orb.make_runner(voc, python=str(py))
    spec = parse_spec({"repeats": 1, "runs": [{"name": "desk", "data": str(seq), "sensor": "rgbd"}]})

    def ours(path, output, **kw):  # a stand-in vslam: the exact ground truth, 5 frames/s
        from vslam.datasets import open_dataset
        from vslam.trajectory import write_tum

        gt = open_dataset(path, sensor="rgbd").ground_truth()
        write_tum(Path(output) / "trajectory.txt", gt)
        return {"frames": 9, "tracked": 9, "fps": 5.0, "ate_rmse": 0.005, "sensor": "rgbd"}

    res = run_benchmark(spec, tmp_path / "bench", executor=LocalExecutor(0), runner=ours,
                        baselines={orb.NAME: runner}, plots=False)
    assert [r["name"] for r in res.rows] == ["desk", "desk@orbslam3"] and res.n_failed == 0
    base = res.rows[1]
    assert base["system"] == "orbslam3" and base["frames"] == 9 and base["fps"] == 9.0
    assert base["ate_rmse"] == pytest.approx(0.01, abs=1e-3)  # +-1 cm, less what SE(3) alignment absorbs
    run_dir = tmp_path / "bench" / "runs" / "desk@orbslam3" / "0"
    assert "fake orbslam3 done" in (run_dir / "orbslam3.log").read_text()
    child = json.loads((run_dir / "stats.json").read_text())
    assert child["vocabulary"] == str(voc.resolve()) and child["pace"] == "mono"
    comp = baseline_comparison(summarize(res.rows))
    assert comp[0]["ate_ratio"] == pytest.approx(0.005 / base["ate_rmse"]) and comp[0]["fps_ratio"] == pytest.approx(5 / 9)
    # on the 9 frames both tracked, from the two trajectory files: ours is the ground truth itself
    assert comp[0]["common_frames"] == 9 and comp[0]["ate_common_vslam"] < 1e-6
    assert comp[0]["ate_common_baseline"] == pytest.approx(base["ate_rmse"], rel=1e-6)
    md = (tmp_path / "bench" / "results.md").read_text()
    assert "## vslam vs baseline" in md and "| desk | rgbd | orbslam3 | 0.0050 | " in md and "| 5.0 | 9.0 | 0.56 |" in md


def test_a_crashing_child_gives_a_failed_row_with_the_signal(tmp_path, shared_data):
    seq = shared_data / "tum_rgbd_freiburg1_desk_9frames"
    voc = tmp_path / "ORBvoc.txt"
    voc.write_text("x")
    py = _write_fake_python(tmp_path / "python", crash=True)
    runner = orb.make_runner(voc, python=str(py))
    with pytest.raises(VslamError, match=r"killed by SIGSEGV.*orbslam3.log"):
        runner(str(seq), tmp_path / "run", sensor="rgbd")
    with pytest.raises(VslamError, match="cannot run the ORB-SLAM3 baseline"):
        orb.make_runner(voc, python=str(_write_fake_python(tmp_path / "python2", check_rc=1)))


def test_comparison_table_marks_paced_baselines():
    rows = [
        {"name": "k07", "repeat": 0, "sensor": "mono", "frames": 10, "tracked": 10, "ate_rmse": 0.3, "fps": 4.0},
        {"name": "k07@orbslam3", "repeat": 0, "sensor": "mono", "frames": 10, "tracked": 5, "ate_rmse": 0.2,
         "fps": 10.0, "system": "orbslam3", "paced": True},
        {"name": "solo", "repeat": 0, "sensor": "mono", "frames": 10, "tracked": 10, "ate_rmse": 0.1, "fps": 4.0},
    ]
    comp = baseline_comparison(summarize(rows))
    assert len(comp) == 1 and comp[0]["ate_ratio"] == pytest.approx(1.5) and comp[0]["fps_ratio"] == pytest.approx(0.4)
    assert comp[0]["tracked_baseline"] == pytest.approx(0.5)
    assert "| k07 | mono | orbslam3 | 0.3000 | 0.2000 | 1.50 | - / - | - | - | 4.0 | 10.0 (paced) | 0.40 | 100 % | 50 % |" \
        in results_markdown(rows)
    rows[0].update(ate_common=0.12, common_frames=5)
    rows[1].update(ate_common=0.2, common_frames=5)
    assert "| 1.50 | 0.1200 / 0.2000 | 0.60 | 5 | 4.0 |" in results_markdown(rows)
    assert "vslam vs baseline" not in results_markdown(rows[2:])


def test_common_frame_ate_scores_both_on_the_frames_both_tracked():
    """A baseline that tracks only the easy first half: on all frames ours looks worse (its error
    sits in the second half), on the frames both tracked ours is compared fairly."""
    from vslam.bench.common_frames import common_frame_ate
    from vslam.trajectory import Trajectory

    n = 20
    t = np.arange(n) * 0.1
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, 0, 3] = np.linspace(0, 2, n)
    T[:, 1, 3] = np.sin(t)
    gt = Trajectory(t, T)
    ours = T.copy()
    ours[:, 2, 3] += np.where(np.arange(n) % 2, 0.002, -0.002)  # +-2 mm everywhere
    ours[12:, 2, 3] += np.linspace(0.0, 0.3, n - 12)  # and a drift in the hard second half
    theirs = T[:10].copy()
    theirs[:, 2, 3] += np.where(np.arange(10) % 2, 0.005, -0.005)  # +-5 mm on the frames it kept
    a, b, k = common_frame_ate(Trajectory(t, ours), Trajectory(t[:10], theirs), gt, "se3")
    assert k == 10
    assert a == pytest.approx(0.002, rel=0.05) and b == pytest.approx(0.005, rel=0.05)


@pytest.mark.slow
def test_real_orbslam3_on_nine_tum_frames(tmp_path, shared_data):
    """One real ORB-SLAM3 run (RGB-D, 9 frames), when $VSLAM_ORBSLAM3_PYTHON and $PYORBSLAM3_VOCAB
    point at a baseline venv and a vocabulary; skipped otherwise."""
    python, vocab = os.environ.get(orb.PYTHON_ENV), os.environ.get(orb.VOCAB_ENV)
    if not python or not vocab:
        pytest.skip(f"set {orb.PYTHON_ENV} and {orb.VOCAB_ENV} to run the real ORB-SLAM3 baseline")
    runner = orb.make_runner(vocab, python=python)
    stats = runner(str(shared_data / "tum_rgbd_freiburg1_desk_9frames"), tmp_path / "run", sensor="rgbd")
    assert stats["frames"] == 9 and stats["tracked"] >= 8
    assert stats["ate_rmse"] < 0.05  # ORB-SLAM3 tracks these 9 frames to a few mm
