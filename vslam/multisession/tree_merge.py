"""Merging the session graph's components pairwise up a tree, in parallel rounds (step 3 of
:mod:`vslam.multisession`; the cluster merging of COLMAP's hierarchical mapper, with ORB-SLAM3's
Atlas map merge, :func:`vslam.merge.merge_maps`, as the weld).

A **cluster** is a map on disk (a session's run folder, or a merge task's output folder) and the
sessions in it: for each, ``S`` (its world -> the cluster's world; SE(3), Sim(3) monocular) and the
``offset`` of its keyframe ids in the cluster's map. At the start every session is a cluster of its
own (or, for ``vslam map --map``, every component of the earlier result is one: see
:func:`clusters_of_result`).

Each **round** (:func:`merge_rounds`):

1. the cluster graph: two clusters are linked by their strongest verified session overlap
   (``inliers``); its maximum spanning forest (Kruskal) is the tree still to merge;
2. a matching of that forest's edges, strongest first, each cluster in at most one pair: on a
   chain of ``n`` sessions about half the edges, so ``O(log n)`` rounds;
3. one task per pair (:func:`merge_task`) on the executor: it loads the two maps from their folders,
   merges the one with fewer keyframes into the other (:func:`vslam.multisession.weld.weld`:
   place recognition of B's keyframes at the seam the verified overlaps found against the whole
   other map, one SE(3) / Sim(3), seam fusion, the seam's local BA; no global BA) and saves the
   result into its own folder under ``work``; what comes back is a small record (the transform,
   the id offset, seam statistics);
4. a pair whose merge finds no overlap after all drops every overlap between its two clusters
   (recorded in ``failed``); their component may still join through other overlaps later.

It ends when no two clusters are linked. The one global step (pose graph over every overlap, global
BA) is :mod:`vslam.multisession.global_opt`, once per component on the final map.
"""
from __future__ import annotations

import logging
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from vslam.multisession.graph import spanning_tree

log = logging.getLogger(__name__)


@dataclass
class Cluster:
    """A map on disk (``folder`` holds ``map/``) and its sessions: ``{name: (S, offset)}``; ``dirty``:
    made by a merge of this run (its pose graph and global BA are still to do)."""

    folder: str
    sessions: dict[str, tuple[np.ndarray, int]]
    keyframes: int
    dirty: bool = False
    merges: list[dict] = field(default_factory=list)

    @property
    def names(self) -> list[str]:
        return list(self.sessions)


def merge_task(a_folder: str, b_folder: str, out_folder: str, config: str | None = None,
               overrides: tuple[str, ...] = (), b_keyframes: list[int] | None = None) -> dict:
    """Task: merge the map in ``b_folder`` into the map in ``a_folder`` (:func:`vslam.multisession.weld.weld`,
    place recognition on ``b_keyframes``, all of B if that finds no overlap) and save the result
    (map, database, camera, metadata, and A's ``config.yaml``) into ``out_folder``. Never raises; a
    record ``{ok, S_a_b, offset, keyframes, ...}`` or ``{ok: False, error}``."""
    from vslam.api import resolve_config
    from vslam.errors import MergeError
    from vslam.map.io import load_run_map, save_map
    from vslam.multisession.weld import weld

    t0 = time.perf_counter()
    try:
        map_a, db_a, cam, meta = load_run_map(a_folder, f"cluster {a_folder}", "merge")
        map_b, db_b, _, _ = load_run_map(b_folder, f"cluster {b_folder}", "merge")
        t_load = time.perf_counter() - t0
        own = Path(a_folder) / "config.yaml"
        cfg_file = config or (str(own) if own.is_file() else None)
        cfg = resolve_config(cfg_file, list(overrides))
        source = str(Path(b_folder).resolve())
        try:
            s = weld(map_a, db_a, map_b, db_b, cam, meta.get("sensor"), cfg, b_keyframes, source)
        except MergeError:
            if not b_keyframes:
                raise
            log.info("no overlap at the known seam of %s; trying every keyframe of it", b_folder)
            s = weld(map_a, db_a, map_b, db_b, cam, meta.get("sensor"), cfg, None, source)
        t1 = time.perf_counter()
        out = Path(out_folder)
        shutil.rmtree(out, ignore_errors=True)
        out.mkdir(parents=True)
        save_map(map_a, out, database=db_a, camera=cam, metadata=dict(meta))
        if cfg_file and Path(cfg_file).is_file():
            shutil.copyfile(cfg_file, out / "config.yaml")
        return {"ok": True, **{k: v for k, v in s.items() if k not in ("S_a_b", "keyframe_id_offset")},
                "S_a_b": np.asarray(s["S_a_b"], float).tolist(), "offset": int(s["keyframe_id_offset"]),
                "load_s": round(t_load, 2), "save_s": round(time.perf_counter() - t1, 2),
                "task_s": round(time.perf_counter() - t0, 2)}
    except MergeError as exc:
        return {"ok": False, "error": str(exc), "task_s": round(time.perf_counter() - t0, 2)}
    except Exception as exc:  # noqa: BLE001 - a merge that fails splits the component, never the run
        return {"ok": False, "error": f"{type(exc).__name__}: {exc}", "task_s": round(time.perf_counter() - t0, 2)}


def seam_keyframes(b: Cluster, a: Cluster, edges: list[dict]) -> list[int] | None:
    """B's keyframes (ids in its cluster map) that the verified overlaps between B's and A's
    sessions matched; None when they name none (overlaps without a recorded seam)."""
    out: set[int] = set()
    for e in edges:
        for mine, other, col in ((e["b"], e["a"], 1), (e["a"], e["b"], 0)):
            if mine in b.sessions and other in a.sessions:
                off = b.sessions[mine][1]
                out |= {int(p[col]) + off for p in e.get("seam") or []}
    return sorted(out) or None


def _failed_merge(args: tuple, message: str) -> dict:
    return {"ok": False, "error": message}


def cluster_links(clusters: list[Cluster], edges: list[dict]) -> list[dict]:
    """The cluster graph: ``{a, b, inliers, edge}`` per linked pair of clusters (indices as names),
    its strongest session overlap between them."""
    where = {n: i for i, c in enumerate(clusters) for n in c.sessions}
    best: dict[tuple[int, int], dict] = {}
    for e in edges:
        if e["a"] not in where or e["b"] not in where:
            continue
        i, j = where[e["a"]], where[e["b"]]
        if i == j:
            continue
        key = (min(i, j), max(i, j))
        if key not in best or e["inliers"] > best[key]["inliers"]:
            best[key] = {"a": key[0], "b": key[1], "inliers": e["inliers"], "edge": e}
    return sorted(best.values(), key=lambda x: (x["a"], x["b"]))


def plan_round(clusters: list[Cluster], edges: list[dict]) -> list[tuple[int, int, dict]]:
    """This round's pairs of cluster indices and the session overlap linking them: a matching of
    the cluster graph's maximum spanning forest, strongest edge first (module docstring)."""
    links = cluster_links(clusters, edges)
    tree = spanning_tree(list(range(len(clusters))), links)
    used: set[int] = set()
    pairs = []
    for t in sorted(tree, key=lambda t: (-t["inliers"], t["a"], t["b"])):
        if t["a"] not in used and t["b"] not in used:
            used |= {t["a"], t["b"]}
            pairs.append((t["a"], t["b"], t["edge"]))
    return pairs


def _joined(a: Cluster, b: Cluster, rec: dict, folder: str) -> Cluster:
    """Cluster ``b`` merged into ``a`` by ``rec`` (``S_a_b``, ``offset``)."""
    S_ab = np.asarray(rec["S_a_b"], float)
    sessions = dict(a.sessions)
    for n, (S, off) in b.sessions.items():
        sessions[n] = (S_ab @ S, off + int(rec["offset"]))
    return Cluster(folder, sessions, int(rec["keyframes"]), True, a.merges + b.merges)


def merge_rounds(clusters: list[Cluster], edges: list[dict], run_tasks: Callable, work: Path,
                 config: str | None = None, overrides: tuple[str, ...] = (),
                 say: Callable[[str], None] = lambda m: None) -> tuple[list[Cluster], list[dict], list[dict]]:
    """Merge linked clusters round by round (module docstring). ``run_tasks(fn, args_list,
    on_error)`` runs the round's tasks (an executor's ``map``). Returns ``(clusters, failed
    overlaps, rounds)``: the final clusters (one per component), the overlaps dropped with their
    error, and per round its pairs and wall time."""
    clusters = list(clusters)
    edges = list(edges)
    failed: list[dict] = []
    rounds: list[dict] = []
    work.mkdir(parents=True, exist_ok=True)
    while True:
        pairs = plan_round(clusters, edges)
        if not pairs:
            break
        r = len(rounds)
        args, order = [], []
        for k, (i, j, _) in enumerate(pairs):
            a, b = (i, j) if (clusters[i].keyframes, -i) >= (clusters[j].keyframes, -j) else (j, i)
            order.append((a, b))
            args.append((clusters[a].folder, clusters[b].folder, str(work / f"r{r}_{k}"), config, tuple(overrides),
                         seam_keyframes(clusters[b], clusters[a], edges)))
        t0 = time.perf_counter()
        results = run_tasks(merge_task, args, _failed_merge)
        wall = time.perf_counter() - t0
        merged: dict[int, Cluster] = {}
        gone: set[int] = set()
        info = []
        for (a, b), (_, _, via), arg, rec in zip(order, pairs, args, results):
            ca, cb = clusters[a], clusters[b]
            step = {"a": ca.names, "b": cb.names, "via": [via["a"], via["b"]],
                    **{k: v for k, v in rec.items() if k not in ("S_a_b",)}}
            info.append(step)
            if rec.get("ok"):
                new = _joined(ca, cb, rec, arg[2])
                new.merges.append({k: step[k] for k in ("a", "b", "via", "seam_keyframes", "alignment_inliers",
                                                        "fused_points", "scale", "task_s")})
                merged[a] = new
                gone.add(b)
                say(f"merge round {r}: {'+'.join(ca.names)} <- {'+'.join(cb.names)}: "
                    f"{rec['seam_keyframes']} seam keyframes, {rec['alignment_inliers']} inliers")
            else:
                between = [e for e in edges if {e["a"], e["b"]} <= set(ca.names) | set(cb.names)
                           and not ({e["a"], e["b"]} <= set(ca.names) or {e["a"], e["b"]} <= set(cb.names))]
                for e in between:
                    edges.remove(e)
                    failed.append({"a": e["a"], "b": e["b"], "error": rec.get("error")})
                log.warning("merging %s with %s failed: %s; their overlaps are dropped", ca.names, cb.names,
                            rec.get("error"))
                say(f"merge round {r}: {'+'.join(ca.names)} / {'+'.join(cb.names)} failed: {rec.get('error')}")
        clusters = [merged.get(i, c) for i, c in enumerate(clusters) if i not in gone]
        rounds.append({"round": r, "pairs": len(pairs), "wall_s": round(wall, 2), "merges": info})
    return clusters, failed, rounds
