"""The HTML report of a run folder and of a benchmark folder (self-contained, plots embedded)."""
from __future__ import annotations

import base64
import json
import re
import struct
import numpy as np
import pytest

from vslam.bench.fake import fake_run
from vslam.errors import VslamError
from vslam.report.html import write_report
from vslam.report.run_data import load_run, loop_positions

IMG_RE = re.compile(r'<img src="data:image/png;base64,([A-Za-z0-9+/=]+)"')


def png_size(b64: str) -> tuple[int, int]:
    data = base64.b64decode(b64)
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    return struct.unpack(">II", data[16:24])


def assert_self_contained(page: str) -> None:
    assert not re.search(r"""(?:src|href|url)\s*[=(]\s*["']?\s*(?:https?:)?//""", page, re.I)
    assert "<link" not in page and "@import" not in page


def test_run_report_has_every_plot_and_the_numbers(tmp_path):
    run = tmp_path / "run"
    fake_run("nowhere", run, sensor="rgbd", overrides=["fake.ate=0.03"], max_frames=20)
    page = write_report(run, tmp_path / "r.html").read_text()
    imgs = IMG_RE.findall(page)
    assert len(imgs) == 4  # trajectory, error along the path, stage timing, sparse map
    assert all(w > 200 and h > 100 for w, h in map(png_size, imgs))
    assert_self_contained(page)
    # the ATE recomputed from trajectory.txt vs groundtruth.txt: every pose is 3 cm off along z with
    # alternating sign (orthogonal to the circle), so SE(3) alignment leaves exactly 0.03 m
    assert "ATE RMSE recomputed here [m]</td><td>0.0300</td>" in page
    assert "<td>ground truth</td><td>groundtruth.txt</td>" in page
    assert "<td>19</td><td>0</td><td>57</td>" in page  # the loop closure table
    for alt in ("trajectory from above vs ground truth", "error along the path", "time per stage",
                "sparse map from above"):
        assert f'alt="{alt}"' in page


def test_loops_are_drawn_between_the_poses_of_their_frames(tmp_path):
    run = tmp_path / "run"
    fake_run("nowhere", run, sensor="rgbd", overrides=["fake.ate=0.0"], max_frames=20, start_frame=5)
    data = load_run(run)
    assert data.evaluation is not None and data.evaluation.ate.rmse < 1e-9
    pos = data.evaluation.alignment.apply(data.est.T_world_cam)[:, :3, 3]
    loops = loop_positions(data, pos)
    assert len(loops) == 1  # stats loop [24, 5, 57]: frames 24 and 5 are rows 19 and 0
    q, m, loop = loops[0]
    assert loop == [24, 5, 57]
    np.testing.assert_allclose(q, pos[19], atol=1e-9)
    np.testing.assert_allclose(m, pos[0], atol=1e-9)


def test_ground_truth_from_the_dataset_named_in_stats(tmp_path, shared_data):
    """No groundtruth.txt: the report opens the dataset at stats.json's path and aligns to its GT."""
    from vslam.datasets import open_dataset
    from vslam.trajectory import Trajectory, write_tum

    seq = shared_data / "tum_rgbd_freiburg1_desk_9frames"
    gt = open_dataset(seq, sensor="rgbd").ground_truth()
    assert gt is not None and len(gt) == 9
    # the estimate: ground truth seen from another world frame (rotated 30 deg about z, shifted)
    c, s = np.cos(np.radians(30)), np.sin(np.radians(30))
    T_other_world = np.array([[c, -s, 0, 1.0], [s, c, 0, -2.0], [0, 0, 1, 0.5], [0, 0, 0, 1]])
    run = tmp_path / "run"
    run.mkdir()
    write_tum(run / "trajectory.txt", Trajectory(gt.timestamps, T_other_world @ gt.T_world_cam))
    (run / "stats.json").write_text(json.dumps({
        "frames": 9, "tracked": 9, "sensor": "rgbd", "dataset": "tum", "path": str(seq),
        "loops": [[8, 0, 30]], "stage_ms": {"track": 10.0}}))
    data = load_run(run)
    assert data.gt_source == f"dataset {seq}"
    assert data.evaluation.matched_poses == 9 and data.evaluation.ate.rmse < 1e-4
    pos = data.evaluation.alignment.apply(data.est.T_world_cam)[:, :3, 3]
    (q, m, _), = loop_positions(data, pos)
    np.testing.assert_allclose(q, gt.positions[8], atol=1e-4)
    np.testing.assert_allclose(m, gt.positions[0], atol=1e-4)
    page = write_report(run, tmp_path / "r.html").read_text()
    assert len(IMG_RE.findall(page)) == 3  # no sparse.ply: no map plot
    assert "ATE RMSE recomputed here [m]</td><td>0.0000</td>" in page


def test_bench_report_links_every_run(tmp_path):
    from vslam.bench.harness import LocalExecutor, run_benchmark
    from vslam.bench.spec import parse_spec

    spec = parse_spec({"repeats": 2, "runs": [{"name": "a", "data": "x"},
                                              {"name": "b", "data": "x", "repeats": 1, "set": {"fake.fail": True}}]},
                      tmp_path, check_config=False)
    bench = tmp_path / "bench"
    run_benchmark(spec, bench, LocalExecutor(0), runner=fake_run, plots=False)
    out = tmp_path / "html" / "bench.html"
    page = write_report(bench, out).read_text()
    assert_self_contained(page)
    assert len(IMG_RE.findall(page)) == 3
    links = re.findall(r'<a href="([^"#]+)">report</a>', page)
    assert len(links) == 3  # the failed run wrote a partial stats.json: its report shows the error
    for link in links:
        assert (out.parent / link).resolve().is_file()
    assert "fake failure" in page and 'id="run-a"' in page and 'href="#run-b"' in page
    assert "the run failed: RuntimeError: fake failure" in (bench / "runs/b/0/report.html").read_text()


def test_not_a_run_folder(tmp_path):
    with pytest.raises(VslamError, match="neither results.json"):
        write_report(tmp_path, tmp_path / "x.html")
    with pytest.raises(VslamError, match="not a folder"):
        write_report(tmp_path / "missing", tmp_path / "x.html")
