"""`vslam map` on the synthetic fleet (issue #26 item 7): four overlapping RGB-D sessions through the
one room (arcs of the room loop, 50 frames of 320 x 240 each, session k overlapping k + 1, each
started at its own origin by `vslam run`) plus one that overlaps nothing (it looks up at the middle
of the ceiling, which no arc sees).

Measured (local executor, 2 workers): one component of four, the lone session apart; ATE over all
200 frames with ONE SE(3) alignment 0.0066 m (per session 0.0061 / 0.0067 / 0.0067 / 0.0069 m under
that alignment); bounds set a little above: 0.010 m overall, 0.012 m per session (issue goal 0.02 m).
The scaling to 32 sessions is benchmarks/multisession_scaling.py (benchmarks/RESULTS.md)."""
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


@pytest.fixture(scope="module")
def mapped(tmp_path_factory) -> dict:
    root = tmp_path_factory.mktemp("synthetic_fleet")
    doc = render_fleet(root / "fleet", 4, n_frames=50)
    out = root / "out"
    rc = main(["map", str(root / "fleet" / "sessions.yaml"), "-o", str(out), "--workers", "2"])
    result = json.loads((out / "sessions.json").read_text()) if rc == 0 else {}
    return {"rc": rc, "out": out, "fleet": root / "fleet", "doc": doc, "result": result}


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
    idx = res["index"]
    assert idx["all_pairs"] == 10 and idx["candidate_pairs"] == len(res["candidates"]) <= 10
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
