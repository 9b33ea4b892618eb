"""`vslam bench` draws every repeat's trajectory of a run (and its baseline's) in one plot,
aligned as the ATE is, beside results.md (issue 25, item 10)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from vslam.bench import overlay
from vslam.bench.fake import fake_run
from vslam.bench.harness import LocalExecutor, run_benchmark
from vslam.bench.spec import parse_spec
from vslam.trajectory import Trajectory, write_tum

PNG = b"\x89PNG\r\n\x1a\n"
SEQUENCE = "tum_fr3_cabinet_keyframes58"  # 58 real TUM frames circling a cabinet, with ground truth


def sequence_runner(noise: float, scale: float, seed: int):
    """The bench's fake runner, its trajectory replaced by the real sequence's ground truth in the
    run's own frame (first camera at the origin), scaled by ``scale`` and with ``noise`` metres of
    position noise per repeat; its ATE computed as `vslam run` does (Sim(3) for mono)."""

    def runner(path, output, **kw):
        from vslam.datasets import open_dataset
        from vslam.eval import evaluate_trajectories

        stats = fake_run(path, output, **kw)
        gt = open_dataset(path).ground_truth()
        rng = np.random.default_rng(seed + int(Path(output).name))
        T = np.linalg.inv(gt.T_world_cam[0]) @ gt.T_world_cam
        T[:, :3, 3] = scale * T[:, :3, 3] + rng.normal(0.0, noise, (len(T), 3))
        est = Trajectory(gt.timestamps, T)
        write_tum(Path(output) / "trajectory.txt", est)
        align = "sim3" if (kw.get("sensor") or "mono") == "mono" else "se3"
        stats["ate_rmse"] = float(evaluate_trajectories(est, gt, align=align).ate.rmse)
        return stats

    return runner


@pytest.fixture
def atomic_writes(monkeypatch):
    """The paths the overlay module writes through vslam.outputs.atomic_write_bytes."""
    written = []
    real = overlay.atomic_write_bytes

    def spy(path, data):
        written.append(Path(path))
        return real(path, data)

    monkeypatch.setattr(overlay, "atomic_write_bytes", spy)
    return written


def test_repeats_and_baseline_of_a_real_sequence_in_one_plot(tmp_path, shared_data, atomic_writes):
    data = shared_data / SEQUENCE
    spec = parse_spec({"repeats": 3, "runs": [{"name": "cab", "data": str(data), "sensor": "mono"}]},
                      tmp_path, check_config=False)
    out = tmp_path / "out"
    res = run_benchmark(spec, out, LocalExecutor(0), runner=sequence_runner(0.02, 0.5, 0),
                        baselines={"orbslam3": sequence_runner(0.04, 2.0, 100)})
    # one PNG for the run, written atomically, listed in results.md
    png = out / "traj_cab.png"
    assert res.files["traj_cab"] == png and png.read_bytes()[:8] == PNG and png.stat().st_size > 20_000
    assert png in atomic_writes
    md = (out / "results.md").read_text()
    assert "## Trajectories" in md and "- `cab`: [traj_cab.png](traj_cab.png)" in md
    # every repeat of vslam and of the baseline, vslam first
    group = overlay.overlay_groups(res.rows, out)["cab"]
    assert [(r["name"], r["repeat"]) for r in group] == [("cab", k) for k in range(3)] + \
        [("cab@orbslam3", k) for k in range(3)]
    # the sequence's own ground truth, not a file of a run folder
    gt, source = overlay.sequence_ground_truth(group, out, spec.runs[0].to_dict())
    assert Path(source) == (data / "groundtruth.txt").resolve() and len(gt) == 58
    # each trajectory aligned as its ATE is: Sim(3) for mono, which undoes the scale 0.5 and 2.0
    curves = overlay.aligned_curves(group, out, gt)
    assert all(c.align == "sim3" and c.aligned for c in curves)
    for c, r in zip(curves, group):
        assert c.ate == pytest.approx(r["ate_rmse"], rel=1e-6)
        assert f"ATE {r['ate_rmse']:.4f} m" in c.label
        err = np.linalg.norm(c.positions - gt.positions, axis=1)
        assert np.sqrt(np.mean(err ** 2)) == pytest.approx(c.ate, rel=1e-6) and c.ate < 0.1
        # the lower panel's curve: the same errors, at the trajectory's own timestamps
        assert np.array_equal(c.error_t, c.timestamps) and np.allclose(c.error, err, rtol=0, atol=1e-12)


def test_se3_for_rgbd_and_no_plot_for_a_lone_trajectory(tmp_path, shared_data):
    data = str(shared_data / SEQUENCE)
    spec = parse_spec({"repeats": 2, "runs": [{"name": "rgbd", "data": data, "sensor": "rgbd"},
                                              {"name": "lone", "data": data, "sensor": "rgbd", "repeats": 1}]},
                      tmp_path, check_config=False)
    out = tmp_path / "out"
    res = run_benchmark(spec, out, LocalExecutor(0), runner=sequence_runner(0.01, 1.0, 7))
    assert (out / "traj_rgbd.png").read_bytes()[:8] == PNG
    assert not (out / "traj_lone.png").exists() and "traj_lone" not in res.files  # its own trajectory.png suffices
    md = (out / "results.md").read_text()
    assert "[traj_rgbd.png](traj_rgbd.png)" in md and "traj_lone" not in md
    group = overlay.overlay_groups(res.rows, out)["rgbd"]
    gt, _ = overlay.sequence_ground_truth(group, out, {})
    curves = overlay.aligned_curves(group, out, gt)
    assert [c.align for c in curves] == ["se3", "se3"]
    assert [c.ate for c in curves] == pytest.approx([r["ate_rmse"] for r in group], rel=1e-6)
    # no plots asked: no overlay either
    res = run_benchmark(spec, tmp_path / "quiet", LocalExecutor(0), runner=sequence_runner(0.01, 1.0, 7), plots=False)
    assert not any(k.startswith("traj_") for k in res.files) and not (tmp_path / "quiet/traj_rgbd.png").exists()


def test_without_ground_truth_every_repeat_is_aligned_to_the_first(tmp_path):
    """A sequence with no ground truth (here: none anywhere) still gets its overlay, every repeat
    aligned to repeat 0 and no ATE in the legend; a failed repeat is left out."""
    (tmp_path / "seq").mkdir()

    def no_gt_runner(path, output, **kw):
        k = int(Path(output).name)
        stats = fake_run(path, output, overrides=[f"fake.ate={0.01 * (k + 1)}", f"fake.fail={k == 2}"],
                         **{key: v for key, v in kw.items() if key != "overrides"})
        (Path(output) / "groundtruth.txt").unlink()
        return stats

    spec = parse_spec({"repeats": 3, "runs": [{"name": "nogt", "data": "seq", "sensor": "rgbd"}]},
                      tmp_path, check_config=False)
    out = tmp_path / "out"
    res = run_benchmark(spec, out, LocalExecutor(0), runner=no_gt_runner)
    assert res.n_failed == 1 and (out / "traj_nogt.png").read_bytes()[:8] == PNG
    group = overlay.overlay_groups(res.rows, out)["nogt"]
    assert [r["repeat"] for r in group] == [0, 1]
    assert overlay.sequence_ground_truth(group, out, {}) == (None, "")
    curves = overlay.aligned_curves(group, out, None)
    assert all(c.ate is None and c.aligned and "ATE" not in c.label and c.error is None for c in curves)
    assert [c.reference for c in curves] == [True, False]
    ref = np.loadtxt(out / "runs/nogt/0/trajectory.txt")[:, 1:4]
    assert np.allclose(curves[0].positions, ref)  # the reference as it is, the other aligned onto it
    assert np.sqrt(np.mean(np.sum((curves[1].positions - ref) ** 2, axis=1))) < 0.031


def test_a_run_folder_ground_truth_is_used_when_the_sequence_has_none(tmp_path):
    """The fake runner's groundtruth.txt (the data folder is no dataset) is the reference."""
    (tmp_path / "seq").mkdir()
    spec = parse_spec({"repeats": 2, "runs": [{"name": "f", "data": "seq", "sensor": "stereo"}]},
                      tmp_path, check_config=False)
    out = tmp_path / "out"
    res = run_benchmark(spec, out, LocalExecutor(0), runner=fake_run)
    group = overlay.overlay_groups(res.rows, out)["f"]
    gt, source = overlay.sequence_ground_truth(group, out, {})
    assert source == "runs/f/0/groundtruth.txt" and len(gt) == 20
    curves = overlay.aligned_curves(group, out, gt)
    assert [c.ate for c in curves] == pytest.approx([0.01, 0.01], abs=1e-6)  # fake.ate, SE(3) cannot undo it
    assert res.files["traj_f"].read_bytes()[:8] == PNG


def test_a_full_disk_keeps_the_previous_overlay(tmp_path, monkeypatch):
    """traj_<run>.png is written atomically: a disk that fills up midway leaves the previous
    plot whole, no temporary file, and a one-line OutputError naming the plot."""
    import errno
    import os

    import vslam.outputs
    from vslam.errors import OutputError

    (tmp_path / "seq").mkdir()
    spec = parse_spec({"repeats": 2, "runs": [{"name": "f", "data": "seq"}]}, tmp_path, check_config=False)
    out = tmp_path / "out"
    out.mkdir()
    (out / "traj_f.png").write_bytes(b"the previous plot")
    real = vslam.outputs._raw_write

    def write(fd, data):
        if not os.path.basename(os.readlink(f"/proc/self/fd/{fd}")).startswith(".traj_f.png.tmp-"):
            return real(fd, data)
        if os.fstat(fd).st_size == 0 and len(data) > 1:
            return real(fd, bytes(data[: len(data) // 2]))
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(vslam.outputs, "_raw_write", write)
    with pytest.raises(OutputError, match="traj_f.png"):
        run_benchmark(spec, out, LocalExecutor(0), runner=fake_run)
    assert (out / "traj_f.png").read_bytes() == b"the previous plot"
    assert not [p for p in out.iterdir() if ".tmp-" in p.name]
