"""The report of a ``vslam localize`` folder (issue #25 item 6): a localized-% row and the counts
it is made of, and no line drawn across the frames that were lost."""
from __future__ import annotations

import json

import numpy as np
import pytest

import vslam.report.charts as charts
from vslam.bench.fake import fake_run
from vslam.localize import counts_line, localize_counts
from vslam.report.html import run_body
from vslam.report.run_data import load_run, lost_gaps, with_breaks
from vslam.trajectory import read_tum, write_tum


@pytest.fixture
def figures(monkeypatch):
    """The axes the report draws, by title, instead of their PNGs."""
    drawn: dict[str, object] = {}

    def keep(fig):
        drawn[fig.axes[0].get_title()] = fig.axes[0]
        return "data:image/png;base64,"

    monkeypatch.setattr(charts, "png_data_uri", keep)
    return drawn


def _localize_folder(tmp_path, with_gt: bool = True):
    """A localize-like folder: 30 frames, 10-17 and 24-25 lost (no pose in trajectory.txt)."""
    folder = tmp_path / "loc"
    fake_run("nowhere", folder, sensor="rgbd", overrides=["fake.ate=0.01"], max_frames=30)
    lost = set(range(10, 18)) | {24, 25}
    est = read_tum(folder / "trajectory.txt")
    write_tum(folder / "trajectory.txt", est.subset(np.array([i for i in range(30) if i not in lost])))
    stats = json.loads((folder / "stats.json").read_text())
    stats.update({"tracked": 17, "relocalizations": 3, "localized": 20, "localized_ratio": 0.6667, "lost": 10,
                  "map": "/maps/kitchen", "matched_poses": 20, "loops": []})
    (folder / "stats.json").write_text(json.dumps(stats))
    if not with_gt:
        (folder / "groundtruth.txt").unlink()
    return folder


def test_counts_are_one_consistent_set():
    c = localize_counts({"frames": 400, "tracked": 340, "relocalizations": 28})
    assert c == {"frames": 400, "localized": 368, "tracked": 340, "relocalized": 28, "imu_only": 0, "lost": 32}
    assert counts_line({"frames": 400, "tracked": 340, "relocalizations": 28}) == \
        "368/400 frames localized (92.0 %: 340 tracked + 28 relocalized), 32 lost"
    # an inertial sensor: frames posed by the IMU alone have a pose but are not localized by vision
    imu = {"frames": 400, "tracked": 340, "relocalizations": 28, "imu_only_frames": 12}
    assert localize_counts(imu)["lost"] == 20
    assert counts_line(imu) == \
        "368/400 frames localized (92.0 %: 340 tracked + 28 relocalized), 12 posed by the IMU alone, 20 lost"


def test_breaks_only_where_frames_were_lost():
    t = np.array([0.0, 0.1, 0.2, 0.6, 0.7, 1.1])
    run = type("R", (), {"frame_times": np.arange(12) * 0.1})()
    assert lost_gaps(run, t).tolist() == [False, False, True, False, True]
    run.frame_times = None  # no dataset: a step over 1.5 median steps
    assert lost_gaps(run, t).tolist() == [False, False, True, False, True]
    xy = with_breaks(np.arange(12.0).reshape(6, 2), lost_gaps(run, t))
    assert xy.shape == (8, 2) and np.isnan(xy[3]).all() and np.isnan(xy[6]).all()


def test_localize_report_has_a_localized_row_and_no_line_across_lost_frames(tmp_path, figures):
    run = load_run(_localize_folder(tmp_path))
    body = run_body(run)
    assert body.startswith("<h1>vslam localize: loc</h1>")
    assert "<tr><td>localized</td><td>20/30 (66.7 %)</td></tr>" in body
    assert "<tr><td>tracked (from the previous frame)</td><td>17</td></tr>" in body
    assert "<tr><td>relocalized</td><td>3</td></tr>" in body and "<td>lost</td><td>10</td>" in body
    # coloured by error: 19 consecutive pairs of poses, 2 of them across lost frames -> 17 segments
    traj = figures["trajectory from above (se3 aligned)"]
    segs = traj.collections[0].get_segments()
    assert len(segs) == 17
    p = run.evaluation.est_aligned.positions
    a, b = charts.top_axes(run.gt.T_world_cam)
    across = {(tuple(p[9, [a, b]]), tuple(p[10, [a, b]])), (tuple(p[15, [a, b]]), tuple(p[16, [a, b]]))}
    assert not any((tuple(s[0]), tuple(s[1])) in across for s in segs)
    err = figures["error along the path"].lines[0].get_ydata()
    assert np.isnan(err).sum() == 2


def test_localize_report_without_ground_truth_breaks_the_line(tmp_path, figures):
    folder = _localize_folder(tmp_path, with_gt=False)
    stats = json.loads((folder / "stats.json").read_text())
    (folder / "stats.json").write_text(json.dumps({**stats, "gt_file": None}))
    run = load_run(folder)
    assert run.gt is None
    run_body(run)
    line = figures["trajectory from above"].lines[0]
    assert np.isnan(line.get_xdata()).sum() == 2 and len(line.get_xdata()) == 22
    smap = figures["sparse map from above (SLAM frame)"].lines[0]
    assert np.isnan(smap.get_xdata()).sum() == 2
