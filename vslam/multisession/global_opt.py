"""The last step of a component (step 3 of :mod:`vslam.multisession`): one pose graph over all its
sessions, with every verified overlap as a constraint (not only the merge tree's), then one global
BA, then its outputs; one task per component (:func:`finalize_task`), on one node.

**Pose graph** (:func:`session_pose_graph`; ORB-SLAM2's essential graph, Mur-Artal & Tardos,
T-RO 2017, sec. V-C, solved by :func:`vslam.map.pose_graph.optimize_pose_graph`, GTSAM; SE(3), and
Sim(3) for monocular sessions, Strasdat et al. RSS 2010). Nodes: every good keyframe of the merged
map. Edges ``(i, j, T_i_j)``:

* *shape*: each keyframe to the previous one of its session, and covisibility links of weight
  >= ``covisibility_weight`` (within and across the welded seams; each keyframe's ``max_covisible``
  strongest, :func:`covisibility_edges`, so the graph stays O(K)), at their relative pose in the
  merged map (what the tree merges and their local BAs made);
* *overlaps*: for every verified overlap ``(a, b)`` of the session graph
  (:func:`vslam.multisession.overlap.verify_pair`), each agreeing seam keyframe pair ``(k_a, k_b)``: ``T_i_j = P_i^-1 P_j`` with
  ``P_i = S_a * T^a_k_a`` (the keyframe's pose in its own run, placed by its session's ``S_a``) and
  ``P_j = (S_a S_a_b) * T^b_k_b``, i.e. where the overlap's own transform puts B's keyframe.
  An overlap edge more than ``max_residual_m`` / ``max_residual_deg`` off the merged map
  (``T_i^-1 T_j`` vs ``T_i_j``) is rejected (counted) rather than allowed to bend the map: a
  wrong verification must not break a good merge.

The component's first keyframe is fixed (the gauge; its scale too, monocular). Keyframes and points
move by their node's correction (:func:`vslam.loop.essential_graph.write_back_corrections`, per
segment). **Global BA**: :meth:`vslam.backend.local_mapping.LocalMapper.global_ba` over every
keyframe and point (each segment's first keyframe fixed; two for monocular), with the settings of
``backend.global_ba`` (its ``merged_relative_tolerance`` as the relative tolerance: the sessions
arrive optimized): its reduced camera system is dense (Cholesky, ``O(K^3)`` per LM step) up to
``sparse_min_cameras`` (200) variable keyframes and block-sparse (SuperLU) above, unless more than a
quarter of the keyframe pairs share points (:mod:`vslam.backend.schur_sparse`). On the synthetic
fleet every session sees the same room, 43 % of the pairs do at 32 sessions, and the dense path is
the faster one (its Cholesky is 18 % of the BA there; the Schur sums are the rest). The pose graph's
covisibility edges grow as ``K^2`` there, and its time is erratic (1-123 s wall at 32 sessions):
benchmarks/RESULTS.md, issue #26 round 3.

Measured (benchmarks/RESULTS.md, issue #26): on the synthetic fleet and on 7-Scenes the global BA
lands on the same poses with or without the pose graph (ATE equal to 4 digits): the tree merges
already weld every seam the overlaps found, and the pose graph moves keyframes by at most 1-10 mm.
Fusing every overlap's seam after the pose graph (ORB-SLAM's SearchAndFuse) was tried and made both
slightly worse (fleet 0.00635 -> 0.00649 m, 7-Scenes 0.0464 -> 0.0467 m); it is not done.
"""
from __future__ import annotations

import dataclasses
import logging
import shutil
import time
from pathlib import Path

import numpy as np

log = logging.getLogger(__name__)


def overlap_edges(sessions: dict[str, tuple[np.ndarray, int]], before: dict[str, dict[int, np.ndarray]],
                  overlaps: list[dict]) -> list[tuple[int, int, np.ndarray, str]]:
    """``(kf_i, kf_j, T_i_j, "a-b")`` in the merged map's keyframe ids, for every seam pair of every
    overlap between two of ``sessions`` (module docstring)."""
    from vslam.geometry.lie import inv_se3
    from vslam.multisession.merging import sim3_poses

    out = []
    for e in overlaps:
        a, b = e["a"], e["b"]
        if a not in sessions or b not in sessions or not e.get("seam"):
            continue
        (S_a, off_a), (_, off_b) = sessions[a], sessions[b]
        S_ab = S_a @ np.asarray(e["S_a_b"], float)
        for ka, kb, _ in e["seam"]:
            if ka not in before[a] or kb not in before[b]:
                continue
            P_i = sim3_poses(S_a, before[a][ka][None])[0]
            P_j = sim3_poses(S_ab, before[b][kb][None])[0]
            out.append((ka + off_a, kb + off_b, inv_se3(P_i) @ P_j, f"{a}-{b}"))
    return out


def covisibility_edges(slam_map, index: dict[int, int], min_weight: int, per_keyframe: int) -> list[tuple[int, int]]:
    """``(a, b)`` with ``a < b``: each keyframe's ``per_keyframe`` strongest covisibility links of
    weight >= ``min_weight`` (either end's choice keeps a link), so the graph has O(K) edges. All
    links of that weight grew as K^2 on the synthetic fleet (one room: 11.4 k edges at 260
    keyframes), and the pose graph's solve with them (benchmarks/RESULTS.md, issue #26)."""
    keep: set[tuple[int, int]] = set()
    for a in index:
        strong = [(w, b) for b, w in slam_map.covisibility.get(a, {}).items() if b in index and b != a and w >= min_weight]
        for w, b in sorted(strong, key=lambda x: (-x[0], x[1]))[:per_keyframe]:
            keep.add((min(a, b), max(a, b)))
    return sorted(keep)


def session_pose_graph(slam_map, sessions: dict[str, tuple[np.ndarray, int]], before: dict[str, dict[int, np.ndarray]],
                       overlaps: list[dict], sensor: str, covisibility_weight: int = 100, max_covisible: int = 10,
                       max_residual_m: float = 0.3, max_residual_deg: float = 10.0) -> dict:
    """Optimize the merged map of ``sessions`` (``{name: (S, offset)}``) with the pose graph of the
    module docstring and move its keyframes and points; returns its statistics."""
    from vslam.geometry.lie import inv_se3, rotation_angle_deg
    from vslam.loop.essential_graph import write_back_corrections
    from vslam.map.pose_graph import optimize_pose_graph

    t0 = time.perf_counter()
    nodes = sorted(k for k, kf in slam_map.keyframes.items() if not kf.bad)
    index = {k: i for i, k in enumerate(nodes)}
    T = np.stack([slam_map.keyframes[k].T_world_cam for k in nodes])
    edges, kinds = [], {"sequence": 0, "covisibility": 0, "overlap": 0, "overlap_rejected": 0}
    for name, (_, off) in sessions.items():
        ids = [k + off for k in sorted(before[name]) if k + off in index]
        for p, q in zip(ids, ids[1:]):
            edges.append((index[p], index[q], inv_se3(T[index[p]]) @ T[index[q]]))
            kinds["sequence"] += 1
    for a, b in covisibility_edges(slam_map, index, covisibility_weight, max_covisible):
        edges.append((index[a], index[b], inv_se3(T[index[a]]) @ T[index[b]]))
        kinds["covisibility"] += 1
    scale = 1.0
    if sensor == "mono":  # metres are unknown: the thresholds relative to the map's extent (5 m room = 1)
        c = T[:, :3, 3]
        scale = max(float(np.linalg.norm(c - c.mean(axis=0), axis=1).max()) / 5.0, 1e-6)
    residuals = []
    for ki, kj, Z, _ in overlap_edges(sessions, before, overlaps):
        if ki not in index or kj not in index:
            continue
        D = inv_se3(Z) @ inv_se3(T[index[ki]]) @ T[index[kj]]
        res_m, res_deg = float(np.linalg.norm(D[:3, 3])), rotation_angle_deg(D)
        if res_m > max_residual_m * scale or res_deg > max_residual_deg:
            kinds["overlap_rejected"] += 1
            continue
        residuals.append(res_m)
        edges.append((index[ki], index[kj], Z))
        kinds["overlap"] += 1
    if not kinds["overlap"]:
        return {"nodes": len(nodes), **kinds, "skipped": "no overlap edge"}
    res = optimize_pose_graph(T, edges, fixed=[0], sim3=sensor == "mono")
    moved = np.linalg.norm(res.T_world_cam[:, :3, 3] - T[:, :3, 3], axis=1)
    segments = np.array([slam_map.keyframes[k].segment for k in nodes])
    for seg in np.unique(segments):
        sel = np.flatnonzero(segments == seg)
        write_back_corrections(slam_map, int(seg), [nodes[i] for i in sel], T[sel], res.S_world_cam[sel])
    return {"nodes": len(nodes), **kinds, "overlap_residual_m_median": round(float(np.median(residuals)), 5),
            "overlap_residual_m_max": round(float(np.max(residuals)), 5),
            "initial_error": round(res.initial_error, 6), "final_error": round(res.final_error, 6),
            "iterations": res.iterations, "moved_m_max": round(float(moved.max()), 5),
            "moved_m_median": round(float(np.median(moved)), 5), "s": round(time.perf_counter() - t0, 3)}


def finalize_task(cluster_folder: str, sessions: dict[str, tuple[list, int]], session_folders: dict[str, str],
                  overlaps: list[dict], out_folder: str, trajectories: str, optimize: bool, pose_graph: bool = True,
                  config: str | None = None, overrides: tuple[str, ...] = ()) -> dict:
    """Task: one component's pose graph and global BA (when ``optimize``: it was merged in this run),
    then its outputs into ``out_folder`` (``map/``, ``sparse.ply``, ``topology.json``, ``config.yaml``)
    and each session's trajectory into ``trajectories/<name>.txt``. Never raises: a failure is the
    record's ``error`` (the other components' outputs are written all the same)."""
    try:
        return _finalize(cluster_folder, sessions, session_folders, overlaps, out_folder, trajectories, optimize,
                         pose_graph, config, overrides)
    except Exception as exc:  # noqa: BLE001 - one component's failure is reported, never the run's
        log.warning("component of %s: %s: %s", ", ".join(sessions), type(exc).__name__, exc)
        return {"error": f"{type(exc).__name__}: {exc}"}


def _finalize(cluster_folder: str, sessions: dict[str, tuple[list, int]], session_folders: dict[str, str],
              overlaps: list[dict], out_folder: str, trajectories: str, optimize: bool, pose_graph: bool,
              config: str | None, overrides: tuple[str, ...]) -> dict:
    from vslam.api import resolve_config
    from vslam.map.io import load_keyframe_poses, load_run_map
    from vslam.multisession.merging import session_trajectory
    from vslam.outputs import atomic_path
    from vslam.reconstruction.map_outputs import write_map_outputs
    from vslam.trajectory import write_tum

    t0 = time.perf_counter()
    placed = {n: (np.asarray(S, float), int(off)) for n, (S, off) in sessions.items()}
    slam_map, db, cam, meta = load_run_map(cluster_folder, "component map", "finalize")
    sensor = meta.get("sensor")
    before = {n: load_keyframe_poses(session_folders[n]) for n in placed}
    load_s = time.perf_counter() - t0
    cfg_file = config or (str(Path(cluster_folder) / "config.yaml")
                          if (Path(cluster_folder) / "config.yaml").is_file() else None)
    stats: dict = {"optimized": bool(optimize and len(placed) > 1)}
    if stats["optimized"]:
        from vslam.backend.local_mapping import LocalMapper

        cfg = resolve_config(cfg_file, list(overrides))
        if pose_graph:
            stats["pose_graph"] = session_pose_graph(slam_map, placed, before, overlaps, sensor)
        t1 = time.perf_counter()
        gba = cfg.backend.global_ba
        backend = dataclasses.replace(cfg.backend, global_ba=dataclasses.replace(
            gba, relative_tolerance=gba.merged_relative_tolerance))
        mapper = LocalMapper(slam_map, cam, sensor, backend, cfg.features.scale_factor)
        mapper.global_ba()
        stats["global_ba"] = mapper.global_ba_result
        stats["global_ba_s"] = round(time.perf_counter() - t1, 2)
    t2 = time.perf_counter()
    out = Path(out_folder)
    out.mkdir(parents=True, exist_ok=True)
    meta = dict(meta)
    meta["sessions"] = list(placed)
    # topology.png: drawn by the report (vslam.report.multisession.draw_topologies), not in this task;
    # an earlier run's would show the old map
    (out / "topology.png").unlink(missing_ok=True)
    write_map_outputs(out, slam_map, camera=cam, database=db, metadata=meta, plots=False)
    if cfg_file and Path(cfg_file).is_file() and Path(cfg_file).resolve() != (out / "config.yaml").resolve():
        with atomic_path(out / "config.yaml") as tmp:
            shutil.copyfile(cfg_file, tmp)
    t3 = time.perf_counter()
    traj_dir = Path(trajectories)
    traj_dir.mkdir(parents=True, exist_ok=True)
    for n, (S, off) in placed.items():
        traj = session_trajectory(slam_map, S, off, before[n], Path(session_folders[n]))
        with atomic_path(traj_dir / f"{n}.txt") as tmp:
            write_tum(tmp, traj)
    t4 = time.perf_counter()
    stats.update(keyframes=len(slam_map.keyframes), points=int(slam_map.points.n_alive),
                 load_s=round(load_s, 2), outputs_s=round(t3 - t2, 2), trajectories_s=round(t4 - t3, 2),
                 task_s=round(t4 - t0, 2))
    return stats
