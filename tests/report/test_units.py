"""Monocular plots and reports without ground truth (issue #25, item 8): the axes of a monocular
run's own frame say "arbitrary scale", not metres, and no ATE is mentioned when there is none."""
from __future__ import annotations

import json
import re

import numpy as np
import pytest

import vslam.report.charts as charts
from vslam.bench.fake import fake_run
from vslam.report.html import run_body, write_report
from vslam.report.run_data import load_run


@pytest.fixture
def figures(monkeypatch):
    """The figures the report draws, by title, instead of their PNGs."""
    drawn: dict[str, object] = {}

    def keep(fig):
        ax = fig.axes[0]
        drawn[ax.get_title()] = ax
        return "data:image/png;base64,"

    monkeypatch.setattr(charts, "png_data_uri", keep)
    return drawn


def _labels(ax) -> tuple[str, str]:
    return ax.get_xlabel(), ax.get_ylabel()


def _run(tmp_path, sensor: str, with_gt: bool):
    run = tmp_path / f"{sensor}_{with_gt}"
    fake_run("nowhere", run, sensor=sensor, overrides=["fake.ate=0.02"], max_frames=12)
    if not with_gt:
        _drop_ground_truth(run)
    return load_run(run)


def _drop_ground_truth(run) -> None:
    """The folder of a run that had no ground truth: no groundtruth.txt, no ATE in stats.json."""
    (run / "groundtruth.txt").unlink()
    stats = json.loads((run / "stats.json").read_text())
    for key in ("ate_rmse", "rpe_trans_rmse", "rpe_rot_deg_rmse", "matched_poses", "scale"):
        stats.pop(key, None)
    (run / "stats.json").write_text(json.dumps({**stats, "gt_file": None}))


def test_mono_without_ground_truth_is_in_arbitrary_units(tmp_path, figures):
    run = _run(tmp_path, "mono", with_gt=False)
    assert run.gt is None and run.evaluation is None
    body = run_body(run)
    traj, smap = figures["trajectory from above"], figures["sparse map from above (SLAM frame)"]
    for ax in (traj, smap):
        assert all(label.endswith("[arbitrary scale]") for label in _labels(ax)), _labels(ax)
    assert "there is no ground truth to fix it" in body and not re.search(r"\bATE\b", body)
    assert 'alt="trajectory from above"' in body


def test_mono_with_ground_truth_is_aligned_into_metres(tmp_path, figures):
    run = _run(tmp_path, "mono", with_gt=True)
    body = run_body(run)
    assert all(label.endswith("[m]") for label in _labels(figures["trajectory from above (sim3 aligned)"]))
    # the map is drawn in the run's own frame: still no metres
    assert _labels(figures["sparse map from above (SLAM frame)"])[0].endswith("[arbitrary scale]")
    assert "Sim(3) alignment" in body and 'alt="trajectory from above vs ground truth"' in body


def test_rgbd_stays_in_metres(tmp_path, figures):
    run = _run(tmp_path, "rgbd", with_gt=False)
    body = run_body(run)
    for title in ("trajectory from above", "sparse map from above (SLAM frame)"):
        assert all(label.endswith("[m]") for label in _labels(figures[title]))
    assert "arbitrary" not in body


def test_topology_plot_of_a_mono_map(tmp_path, monkeypatch):
    from matplotlib.figure import Figure

    from vslam.reconstruction.topology import plot_topology

    saved = []
    monkeypatch.setattr(Figure, "savefig", lambda fig, *a, **k: saved.append(fig.axes[0]))
    nodes = [{"id": i, "T_world_cam": np.eye(4)} for i in range(3)]
    for n in nodes:
        n["T_world_cam"] = n["T_world_cam"].copy()
        n["T_world_cam"][:3, 3] = [n["id"], 0.5 * n["id"] ** 2, 0.0]  # spread along x and y
    edges = [{"source": 0, "target": 1, "kind": "odometry", "weight": 1.0},
             {"source": 1, "target": 2, "kind": "odometry", "weight": 1.0}]
    plot_topology(tmp_path / "t.png", nodes, edges, unit="arbitrary scale")
    plot_topology(tmp_path / "t.png", nodes, edges)
    assert [_labels(ax)[0] for ax in saved] == ["x [arbitrary scale]", "x [m]"]


def test_report_page_of_a_mono_run_without_ground_truth(tmp_path):
    run = tmp_path / "run"
    fake_run("nowhere", run, sensor="mono", max_frames=12)
    _drop_ground_truth(run)
    page = write_report(run, tmp_path / "r.html").read_text()
    assert "there is no ground truth to fix it" in page and not re.search(r"\bATE\b", page)
