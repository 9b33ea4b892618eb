"""`vslam map` on the synthetic fleet (issue #26 item 7): overlapping RGB-D sessions through the one
room (arcs of the room loop, 50 frames of 320 x 240 each, session k overlapping k + 1, each started
at its own origin by `vslam run`) plus one that overlaps nothing (it looks up at the middle of the
ceiling, which no arc sees). Mapped in two steps: s00-s02 + lone, then `vslam map --map OUT` adds
s03 (only it is tracked, searched and verified; it is merged into the kept component map, whose
pose graph and global BA run again).

Measured (local executor, 2 workers): one component of four, the lone session apart; ATE over all
200 frames with ONE SE(3) alignment 0.0061 m (per session 0.0055-0.0065 m under that alignment;
0.0060 m mapped in one step; 0.0066 m with the first version's sequential merges and no pose
graph). Bounds set a little above: 0.010 m overall, 0.012 m per session (issue goal 0.02 m). The
scaling to 32 sessions is benchmarks/multisession_scaling.py (benchmarks/RESULTS.md)."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from vslam.cli import main
from vslam.datasets.synthetic.fleet import LONE, fleet_sessions, render_fleet
from vslam.trajectory import read_tum

ARCS = ["s00", "s01", "s02", "s03"]


def _one_alignment_ate(result: dict, fleet: Path) -> tuple[float, dict[str, float], int]:
    """RMSE over every frame of component 0 after ONE SE(3) alignment to the fleet's ground truth
    (the room's frame); per-session RMSE under that alignment; number of frames."""
    from vslam.eval.joint import joint_ate

    comp = [s for s in result["sessions"] if s.get("component") == 0]
    j = joint_ate({s["name"]: read_tum(s["trajectory"]) for s in comp},
                  {s["name"]: read_tum(fleet / s["name"] / "groundtruth.txt") for s in comp})
    return j.rmse, j.per_name, j.frames


def _spec(path: Path, names: list[str]) -> Path:
    path.write_text("sessions:\n" + "".join(f"  - {{name: {n}, data: {n}, sensor: rgbd}}\n" for n in names))
    return path


@pytest.fixture(scope="module")
def mapped(tmp_path_factory) -> dict:
    root = tmp_path_factory.mktemp("synthetic_fleet")
    doc = render_fleet(root / "fleet", 4, n_frames=50)
    out = root / "out"
    rc1 = main(["map", str(_spec(root / "fleet" / "first.yaml", ARCS[:3] + [LONE])), "-o", str(out), "--workers", "2"])
    first = json.loads((out / "sessions.json").read_text()) if rc1 == 0 else {}
    mtimes = {} if rc1 else {n: (out / "sessions" / n / "stats.json").stat().st_mtime_ns for n in ARCS[:3] + [LONE]}
    rc = rc1 or main(["map", "--map", str(out), str(_spec(root / "fleet" / "more.yaml", ARCS[3:])), "--workers", "2"])
    result = json.loads((out / "sessions.json").read_text()) if rc == 0 else {}
    return {"rc": rc, "out": out, "fleet": root / "fleet", "doc": doc, "result": result, "first": first,
            "mtimes": mtimes}


def test_the_fleet_is_distinct_paths_with_chosen_overlaps() -> None:
    sessions = fleet_sessions(16, n_frames=50)
    assert [s.name for s in sessions][-1] == LONE and len(sessions) == 17
    starts = np.stack([s.T_world_cam[0, :3, 3] for s in sessions])
    assert np.min(np.linalg.norm(starts[:, None] - starts[None], axis=2) + np.eye(17) * 9) > 0.3
    by = {s.name: s for s in sessions}
    for k in range(16):  # k overlaps k + 1, round the closed loop; the lone session overlaps nothing
        assert f"s{(k + 1) % 16:02d}" in by[f"s{k:02d}"].overlaps
        assert LONE not in by[f"s{k:02d}"].overlaps
    assert by[LONE].overlaps == ()
    assert fleet_sessions(32)[20].overlaps and all(np.allclose(np.linalg.det(s.T_world_cam[:, :3, :3]), 1)
                                                   for s in sessions)


def test_a_session_added_later_is_the_only_one_tracked_searched_and_merged(mapped: dict) -> None:
    assert mapped["rc"] == 0
    first, res, out = mapped["first"], mapped["result"], mapped["out"]
    assert first["components"] == [ARCS[:3], [LONE]] and not first["incremental"]
    assert res["incremental"]
    by = {s["name"]: s for s in res["sessions"]}
    assert [n for n in by if not by[n]["reused"]] == ["s03"]
    for n, t in mapped["mtimes"].items():  # the earlier sessions' run folders untouched
        assert (out / "sessions" / n / "stats.json").stat().st_mtime_ns == t
    # only the new session's keyframes queried; only pairs with it verified; the old overlaps kept
    assert res["index"]["queries"] == by["s03"]["keyframes"]
    assert res["candidates"] and all("s03" in (c["a"], c["b"]) for c in res["candidates"])
    old = {frozenset((e["a"], e["b"])) for e in first["overlaps"]}
    assert old <= {frozenset((e["a"], e["b"])) for e in res["overlaps"]}
    # one merge: s03 into the kept map of s00-s02 (a merge of this run has s03 on one side)
    merges = res["component_maps"][0]["merges"]
    assert len(merges) == 1 and ["s03"] in (merges[0]["a"], merges[0]["b"])
    assert res["component_maps"][0]["optimized"] and not res["component_maps"][1]["optimized"]
    assert (out / "report.html").is_file() and "session graph" in (out / "report.html").read_text()
    # the report draws each component's topological map (the finalize task writes only the JSON)
    assert "Topological map" in (out / "report.html").read_text()
    for folder in (out, out / "components" / "1"):
        assert (folder / "topology.json").is_file() and (folder / "topology.png").stat().st_size > 10_000


def test_four_overlapping_sessions_merge_and_the_lone_one_stays_apart(mapped: dict) -> None:
    assert mapped["rc"] == 0
    res, out = mapped["result"], mapped["out"]
    assert res["components"] == [ARCS, [LONE]]
    by = {s["name"]: s for s in res["sessions"]}
    assert all(by[n]["status"] == "ok" and by[n]["frames"] == 50 == by[n]["tracked"] for n in ARCS + [LONE])
    edges = {frozenset((e["a"], e["b"])) for e in res["overlaps"]}
    assert {frozenset(p) for p in zip(ARCS, ARCS[1:])} <= edges  # k and k + 1 verified
    assert all(LONE not in e for e in edges)
    assert all(not c["verified"] for c in res["candidates"] if LONE in (c["a"], c["b"]))
    idx = mapped["first"]["index"]
    assert idx["all_pairs"] == 6 and idx["candidate_pairs"] == len(mapped["first"]["candidates"]) <= 6
    assert res["index"]["all_pairs"] == 4  # s03 with each of the four earlier sessions
    pg = res["component_maps"][0]["pose_graph"]  # every verified overlap's seam pairs, none rejected
    assert pg["overlap"] >= 3 * 5 and pg["overlap_rejected"] == 0
    assert by[LONE]["component"] == 1 and (out / "components" / "1" / "map" / "map.json").is_file()
    np.testing.assert_allclose(np.loadtxt(out / "trajectories" / f"{LONE}.txt"),
                               np.loadtxt(out / "sessions" / LONE / "trajectory.txt"), atol=1e-6)


def test_every_trajectory_in_the_common_frame_with_one_alignment(mapped: dict) -> None:
    assert mapped["rc"] == 0
    ate, per, frames = _one_alignment_ate(mapped["result"], mapped["fleet"])
    assert frames == 200
    assert ate < 0.010, per  # measured 0.0066 m (issue goal 0.02 m)
    assert max(per.values()) < 0.012
    # the start poses were unknown: each session's own run starts at its origin, far from its truth
    for n in ARCS:
        first = np.loadtxt(mapped["out"] / "sessions" / n / "trajectory.txt")[0, 1:4]
        truth = np.loadtxt(mapped["fleet"] / n / "groundtruth.txt")[0, 1:4]
        assert np.linalg.norm(first) < 1e-6 and np.linalg.norm(truth) > 1.0
