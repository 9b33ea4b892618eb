"""Continuing a saved map (`vslam run --map`, issue #18 item 1) and joining segments when they meet
(item 2), on 7-Scenes redkitchen slices (frames 0-299 mapped, 300-599 continued).

The full-size case of the issue (0-499 then 500-999) is measured in benchmarks/RESULTS.md
("Continuing a map"); here shorter slices keep the suite fast."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from vslam.api import run_path
from vslam.cli import main
from vslam.datasets import open_dataset
from vslam.errors import MapFormatError
from vslam.eval.evaluate import evaluate_trajectories
from vslam.map.io import load_map
from vslam.map.segments import segment_table
from vslam.trajectory import Trajectory, read_tum


def _joined_ate(a: Path, b: Path, data: Path) -> tuple[float, int]:
    """ATE of the two runs' trajectories together, under one SE(3) alignment."""
    ta, tb = read_tum(a / "trajectory.txt"), read_tum(b / "trajectory.txt")
    both = Trajectory(np.concatenate([ta.timestamps, tb.timestamps]), np.concatenate([ta.T_world_cam, tb.T_world_cam]))
    r = evaluate_trajectories(both, open_dataset(data).ground_truth(), align="se3")
    return float(r.ate.rmse), len(both)


@pytest.fixture(scope="module")
def kitchen(shared_data: Path, tmp_path_factory) -> dict:
    data = shared_data / "7scenes_redkitchen"
    root = tmp_path_factory.mktemp("continue")
    run_path(data, root / "A", sensor="rgbd", max_frames=300)
    return {"data": data, "root": root}


def test_continued_run_is_in_the_loaded_maps_frame(kitchen: dict, capsys) -> None:
    data, root = kitchen["data"], kitchen["root"]
    rc = main(["run", str(data), "--sensor", "rgbd", "--start-frame", "300", "--max-frames", "300",
               "--map", str(root / "A"), "-o", str(root / "B"), "--no-progress"])
    assert rc == 0
    stats = json.loads((root / "B" / "stats.json").read_text())
    assert stats["tracked"] == 300 and stats["segments"] == 1 and stats["merges"] == []
    # placed on the first frame, in segment 0 of the loaded map
    assert stats["relocalizations"] == 1 and stats["map_segments"] == 1
    # the map loaded and where the session was placed in it: stats.json and the summary
    n_loaded = len(load_map(root / "A")[0].keyframes)
    assert stats["map_loaded"] == str((root / "A").resolve()) and stats["map_keyframes_loaded"] == n_loaded
    assert stats["placed_at_frame"] == 300 and 0 <= stats["placed_keyframe"] < n_loaded
    assert stats["placed_inliers"] >= 20
    line = [l for l in capsys.readouterr().out.splitlines() if l.startswith("map loaded:")]
    assert line == [f"map loaded: {(root / 'A').resolve()} ({n_loaded} keyframes); first frame placed at frame 300 "
                    f"(against its keyframe {stats['placed_keyframe']}, {stats['placed_inliers']} inliers)"]
    ate, n = _joined_ate(root / "A", root / "B", data)
    assert n == 600 and 0.025 < ate < 0.045  # measured 0.0365 (A alone 0.022, B alone 0.0355)
    # the extended map holds the loaded keyframes (same ids, poses moved by BA by millimetres) and the new ones
    a_map, _, _, _ = load_map(root / "A")
    b_map, b_db, _, _ = load_map(root / "B")
    assert set(a_map.keyframes) < set(b_map.keyframes) and len(b_db) == len(b_map.keyframes)
    moved = [np.linalg.norm(b_map.keyframes[k].T_world_cam[:3, 3] - kf.T_world_cam[:3, 3])
             for k, kf in a_map.keyframes.items()]
    assert np.median(moved) < 0.02
    new = [kf for k, kf in b_map.keyframes.items() if k not in a_map.keyframes]
    assert len(new) >= 20 and min(kf.frame_index for kf in new) >= 300
    # local BA connected old and new keyframes: covisibility links across
    assert sum(1 for kf in new for j in b_map.covisibility.get(kf.id, {}) if j in a_map.keyframes) >= 10


def test_unplaced_session_starts_a_segment_and_joins_when_they_meet(kitchen: dict, tmp_path: Path) -> None:
    """Placing disabled (relocalization needs more inliers than exist): after
    ``max_frames_to_place`` frames the session starts segment 1 at the identity; when loop closing
    recognizes the loaded map's place, segment 1 is moved (SE(3)) into segment 0 and welded."""
    data, root = kitchen["data"], kitchen["root"]
    res = run_path(data, tmp_path / "B", sensor="rgbd", start_frame=300, max_frames=300, map_dir=root / "A",
                   overrides=["loop.relocalization.min_inliers=100000", "loop.relocalization.recover_min_inliers=100000",
                              "frontend.tracking.max_frames_to_place=5"])
    s = res.stats
    assert s["segments"] == 1 and len(s["merges"]) == 1
    assert s["placed_at_frame"] is None and s["map_loaded"] == str((root / "A").resolve())
    m = s["merges"][0]
    assert (m["from_segment"], m["into_segment"], m["scale"]) == (1, 0, 1.0) and m["inliers"] >= 30
    assert m["query_frame"] >= 305 and m["match_frame"] < 300
    ate, n = _joined_ate(root / "A", tmp_path / "B", data)
    assert n >= 590 and ate < 0.06
    b_map, _, _, _ = load_map(tmp_path / "B")
    assert {kf.segment for kf in b_map.keyframes.values()} == {0}
    table = segment_table(b_map)
    assert [r.segment for r in table] == [0, 0]
    assert not np.allclose(table[1].S_segment_source, np.eye(4))


def test_map_of_another_sensor_is_refused(kitchen: dict, tmp_path: Path) -> None:
    with pytest.raises(MapFormatError, match="cannot be continued with 'mono'"):
        run_path(kitchen["data"], tmp_path / "B", sensor="mono", start_frame=300, max_frames=5,
                 map_dir=kitchen["root"] / "A")


@pytest.mark.slow
def test_monocular_segments_join_when_the_camera_returns(shared_data: Path) -> None:
    """Monocular 7-Scenes with frames 200-299 dropped and relocalization disabled: tracking is lost,
    a second segment starts with its own frame and scale, and when the camera returns (frame 642 sees
    the place of frame 168) the segments are joined under a Sim(3): one map at the end.

    Which gap shows a join is decided by the chaos of young monocular maps (benchmarks/RESULTS.md,
    round 8, 14 gaps): until round 8 this test dropped 330-399 (join 950 -> 251, ATE 0.0868). With
    the wider monocular local map (``frontend.local_map.keyframes_mono=24``) and 30 lost frames
    before a new segment (``frontend.tracking.max_lost_frames_mono``) that gap's second segment
    starts from a two-view initialization whose translation is nearly unobservable and never joins
    (ATE 0.140 m), while 200-299 now joins well. The measured figures below are the same under
    SandyBridge + generic numba + one thread.

    Each segment's arbitrary monocular scale moves with any change of the mapping; the join's scale
    is the ratio of the two segments' scales at the seam, so it is pinned near its measured value,
    and the joined trajectory's ATE checks it. A segment whose scale drifts cannot be fixed by one
    Sim(3): the inhomogeneous re-triangulation once gave segment 1 a drift 0.19 -> 0.07-0.11
    units/m, a correct seam scale 4.3-4.8 and an ATE of 0.38 m (notes in docs/architecture.md)."""
    from vslam.api import resolve_config
    from vslam.system import System

    data = shared_data / "7scenes_redkitchen"
    cfg = resolve_config(None, ["loop.relocalization.min_inliers=100000", "loop.relocalization.recover_min_inliers=100000"])
    ds = open_dataset(data)
    system = System(cfg, ds.camera, sensor="mono")
    for i in range(1000):
        if not 200 <= i < 300:
            system.track(ds[i])
    system.finish()
    s = system.stats()
    assert s["segments"] == 1 and len(s["merges"]) == 1
    m = s["merges"][0]
    assert (m["from_segment"], m["into_segment"]) == (1, 0) and 600 < m["query_frame"] < 700 and 100 < m["match_frame"] < 250
    assert 2.2 < m["scale"] < 2.75 and m["inliers"] >= 150  # measured 2.464 (frame 642 -> 168), 276
    r = evaluate_trajectories(system.trajectory(), ds.ground_truth(), align="sim3")
    assert len(system.trajectory()) >= 850 and 0.05 < float(r.ate.rmse) < 0.10  # measured 0.0753 over 870 frames
