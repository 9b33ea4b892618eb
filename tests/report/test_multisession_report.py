"""The report page of a `vslam map` result (issue #26 item 5), from a hand-made sessions.json: every
trajectory in one plot per component, the session graph with its edges' inlier counts."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from vslam.errors import VslamError
from vslam.report.multisession import graph_layout, multisession_report_html, write_multisession_report


def _result(tmp_path: Path) -> Path:
    (tmp_path / "trajectories").mkdir(parents=True)
    sessions = []
    for k, name in enumerate(["a", "b", "c", "lone"]):
        t = np.arange(20) / 10.0
        xyz = np.stack([np.cos(t + k), np.sin(t + k), np.full_like(t, 1.0)], axis=1)
        rows = np.column_stack([t + 100 * k, xyz, np.zeros((20, 3)), np.ones(20)])
        np.savetxt(tmp_path / "trajectories" / f"{name}.txt", rows)
        sessions.append({"name": name, "status": "ok", "frames": 20, "keyframes": 4, "reused": False, "error": None,
                         "component": 0 if name != "lone" else 1,
                         "trajectory": str(tmp_path / "trajectories" / f"{name}.txt")})
    sessions.append({"name": "broken", "status": "failed", "error": "DatasetError: no images", "reused": False})
    doc = {"sessions": sessions, "executor": "local (2 processes)",
           "overlaps": [{"a": "a", "b": "b", "inliers": 4321, "in_tree": True},
                        {"a": "b", "b": "c", "inliers": 987, "in_tree": True},
                        {"a": "a", "b": "c", "inliers": 55, "in_tree": False}],
           "components": [["a", "b", "c"], ["lone"]],
           "component_maps": [{"sessions": ["a", "b", "c"], "keyframes": 12, "points": 900, "merges": [{}, {}],
                               "pose_graph": {"overlap": 30}, "folder": str(tmp_path)},
                              {"sessions": ["lone"], "keyframes": 4, "points": 100, "merges": [],
                               "folder": str(tmp_path / "components" / "1")}],
           "timing": {"sessions_s": 1.0, "total_s": 2.0}}
    (tmp_path / "sessions.json").write_text(json.dumps(doc))
    return tmp_path


def test_the_page_shows_every_trajectory_and_the_session_graph(tmp_path: Path) -> None:
    out = _result(tmp_path)
    path = write_multisession_report(out)
    assert path == out / "report.html"
    page = path.read_text()
    assert page.count("data:image/png;base64,") == 2  # trajectories, session graph
    for text in ("4321", "987", "DatasetError: no images", "component", "lone", "broken"):
        assert text in page, text


def test_the_graph_puts_each_component_apart_and_failed_sessions_below(tmp_path: Path) -> None:
    doc = json.loads((_result(tmp_path) / "sessions.json").read_text())
    pos = graph_layout(doc)
    assert set(pos) == {"a", "b", "c", "lone", "broken"}
    xs = {n: p[0] for n, p in pos.items()}
    assert max(xs[n] for n in "abc") < xs["lone"]  # components side by side
    assert pos["broken"][1] < min(pos[n][1] for n in ("a", "b", "c", "lone"))


def test_a_folder_without_sessions_json_is_a_one_line_error(tmp_path: Path) -> None:
    with pytest.raises(VslamError, match="sessions.json"):
        multisession_report_html(tmp_path)


def test_vslam_report_on_a_map_folder_writes_the_map_page(tmp_path: Path) -> None:
    from vslam.cli import main

    out = _result(tmp_path / "out")
    assert main(["report", str(out), "-o", str(tmp_path / "page.html")]) == 0
    page = (tmp_path / "page.html").read_text()
    assert "vslam map: out" in page and page.count("data:image/png;base64,") == 2
