"""`vslam map` (issue #26): many sessions tracked as tasks, overlaps found through one bag-of-words
index and verified per candidate pair, each component merged pairwise up its spanning tree in
parallel rounds, then one pose graph over every verified overlap and a global BA.

Real 7-Scenes redkitchen cut into three overlapping RGB-D sessions (frames 0-199, 150-349,
300-499) plus the TUM fr1/desk clip (another camera: it overlaps nothing) and a missing recording.
The full-length cut (0-399, 300-699, 600-999) gives 0.044 m ATE over all 1200 frames with one
SE(3) alignment (sessions alone, each aligned on its own: 0.025 / 0.040 / 0.034 m)."""
from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest

from vslam.cli import main
from vslam.errors import ConfigError
from vslam.multisession.graph import components, spanning_tree
from vslam.multisession.sessions import parse_inputs

KITCHEN = "7scenes_redkitchen"


def _yaml(path: Path, sessions: list[dict]) -> Path:
    lines = ["sessions:"] + ["  - {" + ", ".join(f"{k}: {v}" for k, v in s.items()) + "}" for s in sessions]
    path.write_text("\n".join(lines) + "\n")
    return path


def _one_alignment_ate(result: dict, data: Path, component: int = 0) -> tuple[float, dict[str, float], int]:
    """RMSE over every frame of every session of ``component`` after ONE SE(3) alignment to ground
    truth; the per-session RMSE under that same alignment; the number of frames."""
    from vslam.datasets import open_dataset
    from vslam.eval.joint import joint_ate
    from vslam.trajectory import read_tum

    gt = open_dataset(data, sensor="rgbd").ground_truth()
    comp = [s for s in result["sessions"] if s.get("component") == component]
    j = joint_ate({s["name"]: read_tum(s["trajectory"]) for s in comp}, {s["name"]: gt for s in comp})
    return j.rmse, j.per_name, j.frames


@pytest.fixture(scope="module")
def fleet(shared_data: Path, tmp_path_factory) -> dict:
    root = tmp_path_factory.mktemp("fleet")
    kitchen = shared_data / KITCHEN
    spec = _yaml(root / "sessions.yaml", [
        {"name": "k0", "data": str(kitchen), "sensor": "rgbd", "max_frames": 200},
        {"name": "k1", "data": str(kitchen), "sensor": "rgbd", "start_frame": 150, "max_frames": 200},
        {"name": "k2", "data": str(kitchen), "sensor": "rgbd", "start_frame": 300, "max_frames": 200},
        {"name": "desk", "data": str(shared_data / "tum_rgbd_freiburg1_desk_9frames"), "sensor": "rgbd"},
        {"name": "missing", "data": str(root / "no_such_recording"), "sensor": "rgbd"},
    ])
    out = root / "out"
    t0 = time.perf_counter()
    rc = main(["map", str(spec), "-o", str(out), "--workers", "2"])
    wall = time.perf_counter() - t0
    result = json.loads((out / "sessions.json").read_text()) if rc == 0 else {}
    return {"rc": rc, "out": out, "result": result, "kitchen": kitchen, "wall": wall}


@pytest.mark.shared
def test_overlapping_sessions_merge_into_one_map_in_one_frame(fleet: dict) -> None:
    assert fleet["rc"] == 0
    out, res = fleet["out"], fleet["result"]
    assert res["components"] == [["k0", "k1", "k2"], ["desk"]]
    by_name = {s["name"]: s for s in res["sessions"]}
    assert all(by_name[n]["status"] == "ok" and by_name[n]["error"] is None for n in ("k0", "k1", "k2", "desk"))
    # the overlap search: one index over every keyframe, one query per keyframe of a session that
    # has a compatible partner (desk's camera differs: it is no candidate); pairs verified <= N * 3
    idx = res["index"]
    assert idx["sessions"] == 4 and idx["all_pairs"] == 6
    assert idx["queries"] == sum(by_name[n]["keyframes"] for n in ("k0", "k1", "k2"))
    assert idx["candidate_pairs"] == len(res["candidates"]) == 3
    edges = {frozenset((e["a"], e["b"])): e for e in res["overlaps"]}
    for pair in (("k0", "k1"), ("k1", "k2")):  # consecutive cuts share 50 frames
        e = edges[frozenset(pair)]
        assert e["verified"] and e["transform"] == "SE(3)" and e["scale"] == 1.0
        # measured: 3091 / 4056 inliers, 16 seam keyframes, residual 0.024 / 0.043 m
        assert e["inliers"] > 1000 and e["seam_keyframes"] >= 5 and 0 < e["residual"] < 0.08
        assert np.asarray(e["S_a_b"]).shape == (4, 4)
    tree = res["component_maps"][0]["tree"]
    assert len(tree) == 2 and {frozenset(t) for t in tree} <= set(edges)
    assert all(e["in_tree"] == (k in {frozenset(t) for t in tree}) for k, e in edges.items())
    # one map, the sessions as segments of it; the trajectories of every frame in its frame
    for name in ("map/map.json", "sparse.ply", "topology.json", "stats.json", "config.yaml", "components/1/map/map.json"):
        assert (out / name).is_file(), name
    from vslam.map.io import load_map
    from vslam.map.segments import segment_table

    merged, db, _, meta = load_map(out)
    assert len(segment_table(merged)) == 3 and meta["sessions"] == ["k0", "k1", "k2"]
    assert len(merged.keyframes) == sum(by_name[n]["keyframes"] for n in ("k0", "k1", "k2")) == len(db)
    for n in ("k0", "k1", "k2", "desk"):
        assert len((out / "trajectories" / f"{n}.txt").read_text().splitlines()) == 1 + {"desk": 9}.get(n, 200)
    # one pose graph over every verified overlap's seam pairs (k0-k2 too, which no merge used):
    # measured 38 overlap edges, none rejected, keyframes moved 1.3 mm median / 5.9 mm at most
    pg = res["component_maps"][0]["pose_graph"]
    assert pg["overlap"] >= 2 * 5 and pg["overlap_rejected"] == 0 and pg["moved_m_max"] < 0.05
    assert res["component_maps"][0]["global_ba"]["keyframes"] >= 0.9 * pg["nodes"]  # measured: all 104
    ate, per, frames = _one_alignment_ate(res, fleet["kitchen"])
    assert frames == 600
    assert ate < 0.05, per  # measured 0.0347 (k0 0.023, k1 0.032, k2 0.045 under the same alignment)
    assert max(per.values()) < 0.06


@pytest.mark.shared
def test_a_merge_verifying_its_seam_in_two_threads_makes_the_same_map(fleet: dict, tmp_path: Path) -> None:
    """merge_task with ``threads=2`` (a lone merge up the tree: vslam.merge.find_seam verifies B's
    keyframes in a thread pool) gives the one-thread merge's transform, seam and fused points exactly:
    the verifications are read-only and each is seeded by its keyframe, the best taken in B's order."""
    from vslam.multisession.tree_merge import merge_task

    sessions = fleet["out"] / "sessions"
    recs = [merge_task(str(sessions / "k1"), str(sessions / "k0"), str(tmp_path / f"t{t}"), threads=t) for t in (1, 2)]
    assert recs[0]["ok"] and recs[0]["seam_keyframes"] >= 5, recs[0]
    keys = ("S_a_b", "offset", "keyframes", "queried_b_keyframes", "seam_keyframes", "alignment_inliers",
            "fused_points", "scale")
    assert {k: recs[1][k] for k in keys} == {k: recs[0][k] for k in keys}


@pytest.mark.shared
def test_a_session_without_overlap_and_a_failed_one_are_reported(fleet: dict) -> None:
    out, res = fleet["out"], fleet["result"]
    by_name = {s["name"]: s for s in res["sessions"]}
    miss = by_name["missing"]
    assert miss["status"] == "failed" and "no_such_recording" in miss["error"] and "DatasetError" in miss["error"]
    assert "component" not in miss and not (out / "trajectories" / "missing.txt").exists()
    desk = by_name["desk"]
    assert desk["component"] == 1 and desk["S_common_session"] == np.eye(4).tolist()
    assert all("desk" not in (e["a"], e["b"]) for e in res["overlaps"] + res["candidates"])
    # its own component: its trajectory is its run's, untouched
    own = np.loadtxt(out / "sessions" / "desk" / "trajectory.txt")
    common = np.loadtxt(out / "trajectories" / "desk.txt")
    np.testing.assert_allclose(common, own, atol=1e-6)
    assert res["component_maps"][1]["folder"] == str(out / "components" / "1")


def _ray_case(shared_data: Path, root: Path) -> Path:
    kitchen = shared_data / KITCHEN
    return _yaml(root / "small.yaml", [
        {"name": "a", "data": str(kitchen), "sensor": "rgbd", "max_frames": 80},
        {"name": "b", "data": str(kitchen), "sensor": "rgbd", "start_frame": 50, "max_frames": 80},
        {"name": "gone", "data": str(root / "missing_recording")},
    ])


@pytest.mark.usefixtures("one_ray_at_a_time")
@pytest.mark.shared
def test_ray_executor_then_a_rerun_resumes_from_the_finished_sessions(shared_data: Path, tmp_path: Path,
                                                                       monkeypatch, capsys) -> None:
    """Sessions and pair verification as Ray tasks on a local Ray (2 CPUs), shut down after; a
    rerun (local, in process) reuses the finished run folders and retries the failed session."""
    pytest.importorskip("ray", reason="ray is not installed (pip install 'vslam[ray]'); CI installs it")
    monkeypatch.setenv("RAY_USAGE_STATS_ENABLED", "0")
    spec, out = _ray_case(shared_data, tmp_path), tmp_path / "out"
    assert main(["map", str(spec), "-o", str(out), "--executor", "ray", "--workers", "2"]) == 0
    printed = capsys.readouterr()
    res = json.loads((out / "sessions.json").read_text())
    assert res["executor"] == "ray (local, 2 CPUs)" and "on ray (local, 2 CPUs)" in printed.err
    assert res["components"] == [["a", "b"]]
    assert [e["verified"] for e in res["candidates"]] == [True]
    by_name = {s["name"]: s for s in res["sessions"]}
    assert by_name["gone"]["status"] == "failed" and "missing_recording" in by_name["gone"]["error"]
    assert not by_name["a"]["reused"] and (out / "trajectories" / "b.txt").is_file()
    assert "2 of 3 sessions mapped, 1 verified overlaps" in printed.out
    import ray

    assert not ray.is_initialized()
    mtime = (out / "sessions" / "a" / "stats.json").stat().st_mtime_ns
    assert main(["map", str(spec), "-o", str(out), "--workers", "0"]) == 0
    again = {s["name"]: s for s in json.loads((out / "sessions.json").read_text())["sessions"]}
    assert again["a"]["reused"] and again["b"]["reused"] and not again["gone"]["reused"]
    assert again["gone"]["status"] == "failed"
    assert (out / "sessions" / "a" / "stats.json").stat().st_mtime_ns == mtime
    assert again["a"]["keyframes"] == by_name["a"]["keyframes"]
    # a session added later (--map): only it is tracked, then it joins the component
    more = _yaml(tmp_path / "more.yaml", [{"name": "c", "data": str(shared_data / KITCHEN), "sensor": "rgbd",
                                           "start_frame": 110, "max_frames": 60}])
    assert main(["map", "--map", str(out), str(more), "--workers", "0"]) == 0
    res = json.loads((out / "sessions.json").read_text())
    added = {s["name"]: s for s in res["sessions"]}
    assert list(added) == ["a", "b", "gone", "c"] and added["a"]["reused"] and not added["c"]["reused"]
    assert res["components"] == [["a", "b", "c"]] and (out / "trajectories" / "c.txt").is_file()
    assert main(["map", "--map", str(out), str(more), "-o", str(tmp_path / "elsewhere")]) == 2


@pytest.mark.shared
def test_monocular_sessions_join_under_a_similarity(shared_data: Path, tmp_path: Path) -> None:
    """KITTI 07 (mono) frames 0-89 and 50-139: the overlap is a Sim(3) (each session has its own
    scale); both trajectories in one frame, evaluated with ONE Sim(3) alignment."""
    from vslam.datasets import open_dataset
    from vslam.eval.metrics import align
    from vslam.trajectory import read_tum

    data = shared_data / "kitti_odometry" / "sequences" / "07"
    spec = _yaml(tmp_path / "mono.yaml", [
        {"name": "m0", "data": str(data), "sensor": "mono", "max_frames": 90},
        {"name": "m1", "data": str(data), "sensor": "mono", "start_frame": 50, "max_frames": 90}])
    assert main(["map", str(spec), "-o", str(tmp_path / "out"), "--workers", "2"]) == 0
    res = json.loads((tmp_path / "out" / "sessions.json").read_text())
    assert res["components"] == [["m0", "m1"]]
    edge = res["overlaps"][0]
    assert edge["transform"] == "Sim(3)" and abs(edge["scale"] - 1.0) > 0.05  # measured 0.63
    gt = open_dataset(data, sensor="mono").ground_truth()
    est, ref = [], []
    for s in res["sessions"]:
        t = read_tum(s["trajectory"])
        idx = np.abs(gt.timestamps[None, :] - t.timestamps[:, None]).argmin(axis=1)
        est.append(t.T_world_cam)
        ref.append(gt.T_world_cam[idx])
    E, G = np.concatenate(est), np.concatenate(ref)
    a = align(E, G, "sim3")
    ate = float(np.sqrt(np.mean(np.sum((E[:, :3, 3] @ (a.s * a.R).T + a.t - G[:, :3, 3]) ** 2, axis=1))))
    assert len(E) == 180 and ate < 0.45  # measured 0.29 m (m0 alone 0.31 m, m1 alone 0.044 m)


def test_inputs_name_the_sessions(tmp_path: Path) -> None:
    (tmp_path / "walk").mkdir()
    (tmp_path / "x" / "walk").mkdir(parents=True)
    specs = parse_inputs([str(tmp_path / "walk"), str(tmp_path / "x" / "walk")], sensor="rgbd")
    assert [s.name for s in specs] == ["walk", "walk-2"] and {s.sensor for s in specs} == {"rgbd"}
    f = _yaml(tmp_path / "s.yaml", [{"data": "walk", "start_frame": 5, "max_frames": 10}, {"name": "b", "data": "x/walk"}])
    specs = parse_inputs([str(f)])
    assert specs[0].name == "walk" and specs[0].data == str(tmp_path / "walk") and specs[0].start_frame == 5
    assert specs[1].name == "b" and specs[1].max_frames is None
    for bad, msg in (([{"data": "walk", "frames": 3}], "unknown key 'frames'"),
                     ([{"name": "a", "data": "walk"}, {"name": "a", "data": "walk"}], "used twice"),
                     ([{"name": "../up", "data": "walk"}], "not a usable folder name"),
                     ([{"data": "walk", "max_frames": 0}], "max_frames"),
                     ([{"data": "walk", "sensor": "rgbd-inertial"}], "sensor")):
        with pytest.raises(ConfigError, match=msg):
            parse_inputs([str(_yaml(tmp_path / "bad.yaml", bad))])
    with pytest.raises(ConfigError, match="only input"):
        parse_inputs([str(f), str(tmp_path / "walk")])


def test_a_session_task_prefetches_in_a_thread_only_with_a_core_to_spare() -> None:
    """Two session tasks with their prefetch threads on two cores tracked in 0.73x the sequential
    time (benchmarks/RESULTS.md): a task gets a prefetch thread only where it has a second core."""
    from vslam.multisession.sessions import session_prefetch

    assert session_prefetch("local", 1, cpus=2) == "thread"
    assert session_prefetch("local", 2, cpus=2) == "none"
    assert session_prefetch("local", 4, cpus=8) == "thread"
    assert session_prefetch("ray", 1, cpus=8) == "none"  # a Ray task asks for one CPU


def test_a_last_wave_with_idle_workers_beside_it_prefetches_in_a_thread() -> None:
    """5 sessions on 2 workers: the fifth runs alone and gets the idle core (7-Scenes: 2.9 s instead
    of 4.3-5.0 s, benchmarks/RESULTS.md); a last wave as large as the workers, or one task beside
    only one idle worker of three, does not; 1 worker never has an idle one."""
    from vslam.multisession.sessions import session_prefetches

    assert session_prefetches("local", 2, 5, cpus=2) == ["none"] * 4 + ["thread"]
    assert session_prefetches("ray", 2, 5, cpus=2) == ["none"] * 4 + ["thread"]  # it asks Ray for one CPU
    assert session_prefetches("local", 2, 4, cpus=2) == ["none"] * 4
    assert session_prefetches("local", 3, 5, cpus=3) == ["none"] * 5  # 2 tasks, 1 idle worker
    assert session_prefetches("local", 4, 5, cpus=4) == ["none"] * 4 + ["thread"]
    assert session_prefetches("local", 1, 3, cpus=2) == ["thread"] * 3  # session_prefetch's own case
    assert session_prefetches("ray", 1, 3, cpus=8) == ["none"] * 3


def test_session_graph_components_and_tree() -> None:
    names = ["a", "b", "c", "d", "e"]
    edges = [{"a": "a", "b": "b", "inliers": 100}, {"a": "b", "b": "c", "inliers": 500},
             {"a": "a", "b": "c", "inliers": 300}, {"a": "d", "b": "e", "inliers": 50}]
    assert components(names, edges) == [["a", "b", "c"], ["d", "e"]]
    assert components(names, []) == [["a"], ["b"], ["c"], ["d"], ["e"]]
    tree = spanning_tree(names, edges)  # the strongest edges that connect: b-c, a-c, d-e (a-b dropped)
    assert [(e["a"], e["b"]) for e in tree] == [("b", "c"), ("a", "c"), ("d", "e")]


def test_map_command_errors_are_one_line(tmp_path: Path, capsys) -> None:
    rc = main(["map", str(tmp_path / "x"), "-o", str(tmp_path / "o"), "--address", "h:1"])
    assert rc == 2 and capsys.readouterr().err.strip() == "vslam map: error: --address is for --executor ray"
    f = _yaml(tmp_path / "s.yaml", [{"data": "x", "bogus": 1}])
    assert main(["map", str(f), "-o", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("vslam map: error: ") and "unknown key 'bogus'" in err and "\n" not in err


def test_a_task_whose_process_dies_is_recorded_and_the_others_go_on() -> None:
    """A killed worker (here ``os._exit``) gives ``on_error``'s record in its place."""
    import os

    from vslam.multisession.executor import TaskExecutor

    with TaskExecutor("local", workers=2) as ex:
        out = ex.map(os._exit, [(3,)], lambda args, msg: {"args": args, "error": msg})
        ok = ex.map(abs, [(-2,), (5,)], lambda args, msg: None)
    assert out[0]["args"] == (3,) and "the task's process failed" in out[0]["error"]
    assert ok == [2, 5]


def test_the_chance_level_from_the_hits_alone_is_the_dense_median() -> None:
    """The overlap search's per-query chance level (median over every keyframe of the other
    sessions, most of them hits) is computed from the inverted index's hits and their count alone."""
    from vslam.multisession.overlap import median_with_zeros

    rng = np.random.default_rng(3)
    for n_total in (1, 2, 5, 50, 51):
        for hits in sorted({0, 1, n_total // 3, n_total // 2, n_total - 1, n_total}):
            v = rng.random(hits)
            dense = np.concatenate([v, np.zeros(n_total - hits)])
            assert median_with_zeros(v, n_total) == pytest.approx(float(np.median(dense)), abs=0, rel=1e-15)


def _contract(n: int, weights: list[float]) -> int:
    """Rounds of :func:`plan_round` to merge a chain of ``n`` sessions (maps replaced by records)."""
    from vslam.multisession.tree_merge import Cluster, plan_round

    clusters = [Cluster(f"/x/{i}", {f"s{i}": (np.eye(4), 0)}, 10) for i in range(n)]
    edges = [{"a": f"s{i}", "b": f"s{i + 1}", "inliers": w} for i, w in enumerate(weights)]
    rounds = 0
    while True:
        pairs = plan_round(clusters, edges)
        if not pairs:
            return rounds if len(clusters) == 1 else -1
        gone = set()
        for i, j, _ in pairs:
            clusters[i] = Cluster("", {**clusters[i].sessions, **clusters[j].sessions}, 20)
            gone.add(j)
        clusters = [c for k, c in enumerate(clusters) if k not in gone]
        rounds += 1


def test_the_tree_merge_takes_logarithmic_rounds_on_a_chain() -> None:
    """Pairs of each round are a maximum matching of the cluster graph's spanning tree: a chain of
    ``n`` (the fleet's ring opened at its weakest overlap) needs ceil(log2 n) rounds whatever its
    weights, where the sequential merge took n - 1 (strongest-first matching, before: 4-5 rounds
    for 16 sessions over these seeds, since it can leave two neighbours unmatched)."""
    assert _contract(16, [100] * 15) == 4
    rng = np.random.default_rng(0)
    assert {_contract(16, list(rng.integers(50, 5000, 15))) for _ in range(20)} == {4}
    assert {_contract(17, list(rng.integers(50, 5000, 16))) for _ in range(5)} == {5}
    assert _contract(32, [100] * 31) == 5


def test_forest_matching_is_maximum_on_random_trees() -> None:
    """:func:`forest_matching` against the largest matching found by trying every edge subset, on
    random forests of up to 9 nodes (stars, chains and everything between): a matching (no node
    twice) of maximum size."""
    from itertools import combinations

    from vslam.multisession.graph import forest_matching

    rng = np.random.default_rng(7)
    for _ in range(200):
        n = int(rng.integers(2, 10))
        tree = [{"a": int(rng.integers(0, v)), "b": v, "inliers": int(rng.integers(10, 1000))}
                for v in range(1, n) if rng.random() < 0.9]
        got = forest_matching(tree)
        nodes = [v for t in got for v in (t["a"], t["b"])]
        assert len(nodes) == len(set(nodes)) and all(t in tree for t in got)
        best = max((k for k in range(len(tree) + 1) for sub in combinations(tree, k)
                    if len({v for t in sub for v in (t["a"], t["b"])}) == 2 * k), default=0)
        assert len(got) == best, (tree, got)


def test_overlap_edges_put_each_seam_pair_where_the_overlap_says() -> None:
    """Two sessions with exact keyframe poses in their own worlds, placed in the common frame by
    ``S_a`` and ``S_b = S_a S_a_b``: each seam pair's edge is the true relative pose (SE(3) and
    Sim(3) placements)."""
    from vslam.geometry.lie import inv_se3, so3_exp
    from vslam.multisession.global_opt import overlap_edges
    from vslam.multisession.merging import sim3_poses

    rng = np.random.default_rng(1)

    def rigid() -> np.ndarray:
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = so3_exp(rng.normal(size=3)), rng.normal(size=3)
        return T

    for scale in (1.0, 0.6):
        truth = {k: rigid() for k in range(6)}  # common-frame poses of 6 keyframes (3 per session)
        S_a, S_b = rigid(), rigid()
        S_b[:3, :3] *= scale
        S_a_b = np.linalg.inv(S_a) @ S_b
        before = {"a": {k: sim3_poses(np.linalg.inv(S_a), truth[k][None])[0] for k in range(3)},
                  "b": {k - 3: sim3_poses(np.linalg.inv(S_b), truth[k][None])[0] for k in range(3, 6)}}
        sessions = {"a": (S_a, 0), "b": (S_b, 10)}
        edges = overlap_edges(sessions, before, [{"a": "a", "b": "b", "S_a_b": S_a_b.tolist(),
                                                   "seam": [[0, 1, 50], [2, 0, 40], [9, 0, 10]]}])
        assert [(i, j) for i, j, _, _ in edges] == [(0, 11), (2, 10)]  # kf 9 of a does not exist
        for i, j, Z, _ in edges:
            np.testing.assert_allclose(Z, inv_se3(truth[i]) @ truth[j - 10 + 3], atol=1e-9)


def test_a_failed_merge_drops_its_overlaps_and_the_rest_still_merge(tmp_path: Path) -> None:
    """merge_rounds with the merge tasks replaced by records: the merge of {c} into {a, b} fails
    (no overlap after all), so c stays its own component with the failure recorded, while d, linked
    to b too, joins; placements compose (S of a session merged twice = product of the transforms)."""
    from vslam.multisession.tree_merge import Cluster, merge_rounds

    shift = np.eye(4)
    shift[0, 3] = 1.0
    calls = []

    def run_tasks(fn, args_list, on_error):
        out = []
        for a_folder, b_folder, folder, *_ in args_list:
            calls.append((Path(a_folder).name, Path(b_folder).name))
            if Path(b_folder).name == "c" or Path(a_folder).name == "c":
                out.append({"ok": False, "error": "no overlap"})
            else:
                out.append({"ok": True, "S_a_b": shift.tolist(), "offset": 100, "keyframes": 20, "seam_keyframes": 3,
                            "alignment_inliers": 500, "fused_points": 10, "scale": 1.0, "task_s": 0.1})
        return out

    clusters = [Cluster(str(tmp_path / n), {n: (np.eye(4), 0)}, 10 - i) for i, n in enumerate("abcd")]
    edges = [{"a": "a", "b": "b", "inliers": 900}, {"a": "b", "b": "c", "inliers": 800},
             {"a": "b", "b": "d", "inliers": 300}]
    final, failed, rounds = merge_rounds(clusters, edges, run_tasks, tmp_path / "work")
    assert sorted(sorted(c.sessions) for c in final) == [["a", "b", "d"], ["c"]]
    assert failed == [{"a": "b", "b": "c", "error": "no overlap"}]
    abd = next(c for c in final if "a" in c.sessions)
    S_d, off_d = abd.sessions["d"]
    assert off_d == 100 and S_d[0, 3] == 1.0 and abd.sessions["b"][1] == 100 and abd.sessions["a"][1] == 0
    assert [r["pairs"] for r in rounds] == [1, 1, 1] and len(calls) == 3


class _FakeMerges:
    """A stand-in for :func:`merge_task` over folders that are names only: a merged map has the
    keyframes of both, ``S_a_b`` a shift drawn from the output's name; ``fail`` names the outputs
    whose merge fails; ``hooks[out]`` runs first (blocking on an event, ...)."""

    def __init__(self, keyframes: dict[str, int], fail: tuple[str, ...] = (), hooks: dict | None = None) -> None:
        self.keyframes, self.fail, self.hooks, self.calls = dict(keyframes), fail, hooks or {}, []
        self.threads: dict[str, int] = {}

    def __call__(self, a_folder, b_folder, out_folder, config=None, overrides=(), b_keyframes=None,
                 threads=1) -> dict:
        out = Path(out_folder).name
        self.calls.append((Path(a_folder).name, Path(b_folder).name, out, b_keyframes))
        self.threads[out] = threads
        if out in self.hooks:
            self.hooks[out]()
        if out in self.fail:
            return {"ok": False, "error": "no overlap", "task_s": 0.0}
        ka, kb = self.keyframes[Path(a_folder).name], self.keyframes[Path(b_folder).name]
        self.keyframes[out] = ka + kb
        S = np.eye(4)
        S[:3, 3] = [len(out), sum(map(ord, out)) % 7, ka]
        return {"ok": True, "S_a_b": S.tolist(), "offset": ka, "keyframes": ka + kb, "seam_keyframes": 3,
                "alignment_inliers": 500, "fused_points": 10, "scale": 1.0, "task_s": 0.0}


class _ThreadExecutor:
    """TaskExecutor's ``map`` / ``submit`` / ``wait_any`` / ``slots`` on threads, running ``fake`` in
    place of the task function."""

    def __init__(self, fake: _FakeMerges, slots: int) -> None:
        import concurrent.futures as cf

        self.fake, self.slots, self.cf = fake, slots, cf
        self.pool = cf.ThreadPoolExecutor(max_workers=slots)
        self.cpus: dict[str, int] = {}

    def map(self, fn, args_list, on_error):
        return [self.fake(*args) for args in args_list]

    def submit(self, fn, args, on_error, cpus=1):
        self.cpus[Path(args[2]).name] = cpus
        return self.pool.submit(self.fake, *args)

    def wait_any(self, tasks):
        done, _ = self.cf.wait(tasks, return_when=self.cf.FIRST_COMPLETED)
        task = next(t for t in tasks if t in done)
        return task, task.result()


def _fleet(n: int, ring: bool, seed: int, tmp_path: Path) -> tuple[list, list[dict], dict[str, int]]:
    from vslam.multisession.tree_merge import Cluster

    rng = np.random.default_rng(seed)
    kf = {f"s{i}": int(rng.integers(5, 40)) for i in range(n)}
    clusters = [Cluster(str(tmp_path / f"s{i}"), {f"s{i}": (np.eye(4), 0)}, kf[f"s{i}"]) for i in range(n)]
    edges = [{"a": f"s{i}", "b": f"s{(i + 1) % n}", "inliers": int(rng.integers(50, 5000)),
              "seam": [[i, i + 1, 40]]} for i in range(n if ring else n - 1)]
    return clusters, edges, kf


def _outcome(final, failed, rounds) -> tuple:
    clusters = sorted((Path(c.folder).name, {n: (S.tolist(), off) for n, (S, off) in c.sessions.items()},
                       c.keyframes, c.merges) for c in final)
    return clusters, failed, [(r["round"], r["pairs"], r["merges"]) for r in rounds]


def test_the_planned_tree_is_the_rounds_merges(tmp_path: Path) -> None:
    """plan_tree (every merge assumed to succeed, a merged map has both maps' keyframes) gives the
    merges merge_rounds makes, pair by pair, orientation and folder included, on chains and rings;
    merge_tree (dataflow, on 1 to 3 workers) gives the same clusters, placements and records."""
    from vslam.multisession.tree_merge import merge_rounds, merge_tree, plan_tree

    for n, ring, seed in ((16, False, 0), (16, True, 1), (9, False, 2), (13, True, 3), (2, False, 4)):
        clusters, edges, kf = _fleet(n, ring, seed, tmp_path)
        fake = _FakeMerges(kf)
        expected = _outcome(*merge_rounds(clusters, edges, _ThreadExecutor(fake, 1).map, tmp_path / "w"))
        rounds_calls = list(fake.calls)
        states, plan, keyframes = plan_tree(clusters, edges)
        name = {i: f"s{i}" for i in range(n)} | {m.out: f"r{m.r}_{m.k}" for ms in plan for m in ms}
        assert [(name[m.a], name[m.b], name[m.out]) for ms in plan for m in ms] == [c[:3] for c in rounds_calls]
        assert len(states[-1]) == 1 and keyframes[states[-1][0]] == sum(kf.values())
        for slots in (1, 2, 3):
            fake = _FakeMerges(kf)
            got = _outcome(*merge_tree(clusters, edges, _ThreadExecutor(fake, slots), tmp_path / "w"))
            assert got == expected
            assert sorted(fake.calls) == sorted(rounds_calls)  # seam keyframes included


def test_a_merge_starts_once_its_clusters_exist_not_at_the_end_of_its_round(tmp_path: Path) -> None:
    """A chain of 6: round 0 merges s0+s1, s2+s3, s4+s5; round 1 (s0..s3) needs only the first two.
    With 2 workers and the s4+s5 merge held until the round-1 merge has started, the dataflow
    starts it before that merge ends (the rounds would wait for all of round 0: the held merge's
    wait would time out). No timing is asserted: the held merge only waits on an event."""
    import threading

    from vslam.multisession.tree_merge import merge_tree

    clusters, edges, kf = _fleet(6, False, 0, tmp_path)
    for e in edges:
        e["inliers"] = 100
    started = threading.Event()
    waited = []
    fake = _FakeMerges(kf, hooks={"r1_0": started.set, "r0_2": lambda: waited.append(started.wait(60))})
    ex = _ThreadExecutor(fake, 2)
    final, failed, rounds = merge_tree(clusters, edges, ex, tmp_path / "w")
    assert waited == [True]
    assert [r["pairs"] for r in rounds] == [3, 1, 1] and len(final) == 1 and not failed
    order = [c[2] for c in fake.calls]
    assert order.index("r1_0") < order.index("r2_0") and order[-1] == "r2_0"
    # a merge that is the only one ready verifies in a second thread: the last (and asks the executor
    # for 2 CPUs: nothing else runs), round 1's and the third of round 0 (1 CPU each: they start
    # beside a running merge); the first two of round 0 start together
    assert fake.threads == {"r0_0": 1, "r0_1": 1, "r0_2": 2, "r1_0": 2, "r2_0": 2}
    assert ex.cpus == {**fake.threads, "r0_2": 1, "r1_0": 1}
    fake = _FakeMerges(kf)
    merge_tree(clusters, edges, _ThreadExecutor(fake, 1), tmp_path / "w1")
    assert set(fake.threads.values()) == {1}  # one slot: nothing to spare


def test_a_failed_merge_mid_tree_goes_on_round_by_round(tmp_path: Path) -> None:
    """A merge of round 1 fails: the rest of round 1 still merges, what the dataflow started after it
    is dropped, and the rounds go on from there: the outcome (clusters, failures, records) is
    merge_rounds's, on any number of workers; the 4-cluster case of the failed-merge test too."""
    from vslam.multisession.tree_merge import Cluster, merge_rounds, merge_tree

    for n, ring, seed, fail in ((16, False, 0, ("r1_1",)), (16, True, 1, ("r0_3", "r2_0")), (9, False, 2, ("r0_0",))):
        clusters, edges, kf = _fleet(n, ring, seed, tmp_path)
        expected = _outcome(*merge_rounds(clusters, edges, _ThreadExecutor(_FakeMerges(kf, fail), 1).map,
                                          tmp_path / "w"))
        assert expected[1]  # something failed
        for slots in (1, 2, 3):
            got = _outcome(*merge_tree(clusters, edges, _ThreadExecutor(_FakeMerges(kf, fail), slots), tmp_path / "w"))
            assert got == expected
    clusters = [Cluster(str(tmp_path / n), {n: (np.eye(4), 0)}, 10 - i) for i, n in enumerate("abcd")]
    edges = [{"a": "a", "b": "b", "inliers": 900}, {"a": "b", "b": "c", "inliers": 800},
             {"a": "b", "b": "d", "inliers": 300}]
    fake = _FakeMerges({n: 10 - i for i, n in enumerate("abcd")}, fail=("r1_0",))
    final, failed, rounds = merge_tree(clusters, edges, _ThreadExecutor(fake, 2), tmp_path / "w")
    assert sorted(sorted(c.sessions) for c in final) == [["a", "b", "d"], ["c"]]
    assert failed == [{"a": "b", "b": "c", "error": "no overlap"}] and [r["pairs"] for r in rounds] == [1, 1, 1]


def test_submitted_tasks_come_back_one_by_one_and_a_dying_one_is_recorded() -> None:
    """TaskExecutor.submit / wait_any: in process (done at once) and on a pool of 2, where a task
    that kills its worker gives on_error's record and the others their results."""
    import os

    from vslam.multisession.executor import TaskExecutor

    def collect(ex, tasks) -> dict:
        out = {}
        pending = list(tasks)
        while pending:
            task, result = ex.wait_any(pending)
            pending.remove(task)
            out[task.args] = result
        return out

    on_error = lambda args, msg: {"error": msg}  # noqa: E731
    with TaskExecutor("local", workers=0) as ex:
        tasks = [ex.submit(abs, (-3,), on_error), ex.submit(abs, (4,), on_error)]
        assert all(t.done for t in tasks) and collect(ex, tasks) == {(-3,): 3, (4,): 4} and ex.slots == 1
    with TaskExecutor("local", workers=2) as ex:
        out = collect(ex, [ex.submit(os._exit, (3,), on_error), ex.submit(abs, (-2,), on_error)])
        assert out[(-2,)] == 2 and "the task's process failed" in out[(3,)]["error"]
        assert collect(ex, [ex.submit(abs, (-5,), on_error)]) == {(-5,): 5} and ex.slots == 2
