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
2. a maximum matching of that forest's edges (:func:`vslam.multisession.graph.forest_matching`:
   the strongest edge at a leaf first), each cluster in at most one pair: on a chain of ``n``
   sessions ``floor(n / 2)`` pairs, so ``ceil(log2 n)`` rounds;
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

:func:`merge_tree` (what ``vslam map`` runs) makes the same merges without the barrier between
rounds: it plans every round first (:func:`plan_tree`: a merged cluster's keyframes are the sum of
its two), then starts each merge as soon as its two clusters exist (the one with the longest chain
of merges still to follow first). A merge's inputs, orientation and folder are those of its round,
so the maps are the rounds' whatever the timing; after a failed merge it goes on round by round.
"""
from __future__ import annotations

import logging
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from vslam.multisession.graph import forest_matching, spanning_tree

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
               overrides: tuple[str, ...] = (), b_keyframes: list[int] | None = None, threads: int = 1) -> dict:
    """Task: merge the map in ``b_folder`` into the map in ``a_folder`` (:func:`vslam.multisession.weld.weld`,
    place recognition on ``b_keyframes``, all of B if that finds no overlap, verified in ``threads``
    threads) and save the result (map, database, camera, metadata, and A's ``config.yaml``) into
    ``out_folder``. Never raises; a record ``{ok, S_a_b, offset, keyframes, ...}`` or ``{ok: False, error}``."""
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
            s = weld(map_a, db_a, map_b, db_b, cam, meta.get("sensor"), cfg, b_keyframes, source, threads)
        except MergeError:
            if not b_keyframes:
                raise
            log.info("no overlap at the known seam of %s; trying every keyframe of it", b_folder)
            s = weld(map_a, db_a, map_b, db_b, cam, meta.get("sensor"), cfg, None, source, threads)
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
    """This round's pairs of cluster indices and the session overlap linking them: a maximum
    matching of the cluster graph's maximum spanning forest (module docstring)."""
    tree = spanning_tree(list(range(len(clusters))), cluster_links(clusters, edges))
    return [(t["a"], t["b"], t["edge"]) for t in forest_matching(tree)]


def _joined(a: Cluster, b: Cluster, rec: dict, folder: str) -> Cluster:
    """Cluster ``b`` merged into ``a`` by ``rec`` (``S_a_b``, ``offset``)."""
    S_ab = np.asarray(rec["S_a_b"], float)
    sessions = dict(a.sessions)
    for n, (S, off) in b.sessions.items():
        sessions[n] = (S_ab @ S, off + int(rec["offset"]))
    return Cluster(folder, sessions, int(rec["keyframes"]), True, a.merges + b.merges)


def _oriented(clusters: list, i: int, j: int) -> tuple[int, int]:
    """``(a, b)`` of a pair: B (merged into A) is the one with fewer keyframes (ties: the later)."""
    return (i, j) if (clusters[i].keyframes, -i) >= (clusters[j].keyframes, -j) else (j, i)


def _task_args(a: Cluster, b: Cluster, folder: str, edges: list[dict], config: str | None,
               overrides: tuple[str, ...], threads: int = 1) -> tuple:
    return (a.folder, b.folder, folder, config, tuple(overrides), seam_keyframes(b, a, edges), threads)


def _step(ca: Cluster, cb: Cluster, via: dict, rec: dict, folder: str) -> tuple[Cluster | None, dict]:
    """A merge's record in ``rounds`` and, if it succeeded, the joined cluster."""
    step = {"a": ca.names, "b": cb.names, "via": [via["a"], via["b"]],
            **{k: v for k, v in rec.items() if k not in ("S_a_b",)}}
    if not rec.get("ok"):
        return None, step
    new = _joined(ca, cb, rec, folder)
    new.merges.append({k: step[k] for k in ("a", "b", "via", "seam_keyframes", "alignment_inliers",
                                            "fused_points", "scale", "task_s")})
    return new, step


def _report(r: int, ca: Cluster, cb: Cluster, rec: dict, edges: list[dict], failed: list[dict],
            say: Callable[[str], None]) -> None:
    """Say how a merge went; a failed one drops the overlaps between its two clusters (``failed``)."""
    if rec.get("ok"):
        say(f"merge round {r}: {'+'.join(ca.names)} <- {'+'.join(cb.names)}: "
            f"{rec['seam_keyframes']} seam keyframes, {rec['alignment_inliers']} inliers")
        return
    between = [e for e in edges if {e["a"], e["b"]} <= set(ca.names) | set(cb.names)
               and not ({e["a"], e["b"]} <= set(ca.names) or {e["a"], e["b"]} <= set(cb.names))]
    for e in between:
        edges.remove(e)
        failed.append({"a": e["a"], "b": e["b"], "error": rec.get("error")})
    log.warning("merging %s with %s failed: %s; their overlaps are dropped", ca.names, cb.names, rec.get("error"))
    say(f"merge round {r}: {'+'.join(ca.names)} / {'+'.join(cb.names)} failed: {rec.get('error')}")


def merge_rounds(clusters: list[Cluster], edges: list[dict], run_tasks: Callable, work: Path,
                 config: str | None = None, overrides: tuple[str, ...] = (),
                 say: Callable[[str], None] = lambda m: None, failed: list[dict] | None = None,
                 rounds: list[dict] | None = None) -> tuple[list[Cluster], list[dict], list[dict]]:
    """Merge linked clusters round by round (module docstring). ``run_tasks(fn, args_list,
    on_error)`` runs the round's tasks (an executor's ``map``). Returns ``(clusters, failed
    overlaps, rounds)``: the final clusters (one per component), the overlaps dropped with their
    error, and per round its pairs and wall time. ``failed`` / ``rounds``: those of the rounds
    already done (the rounds go on from there; ``edges`` is then their edges, failures dropped)."""
    clusters = list(clusters)
    edges = list(edges)
    failed = list(failed or [])
    rounds = list(rounds or [])
    work.mkdir(parents=True, exist_ok=True)
    while True:
        pairs = plan_round(clusters, edges)
        if not pairs:
            break
        r = len(rounds)
        order = [_oriented(clusters, i, j) for i, j, _ in pairs]
        args = [_task_args(clusters[a], clusters[b], str(work / f"r{r}_{k}"), edges, config, overrides)
                for k, (a, b) in enumerate(order)]
        t0 = time.perf_counter()
        results = run_tasks(merge_task, args, _failed_merge)
        wall = time.perf_counter() - t0
        merged: dict[int, Cluster] = {}
        gone: set[int] = set()
        info = []
        for (a, b), (_, _, via), arg, rec in zip(order, pairs, args, results):
            new, step = _step(clusters[a], clusters[b], via, rec, arg[2])
            info.append(step)
            _report(r, clusters[a], clusters[b], rec, edges, failed, say)
            if new is not None:
                merged[a] = new
                gone.add(b)
        clusters = [merged.get(i, c) for i, c in enumerate(clusters) if i not in gone]
        rounds.append({"round": r, "pairs": len(pairs), "wall_s": round(wall, 2), "merges": info})
    return clusters, failed, rounds


@dataclass(eq=False)
class PlannedMerge:
    """One merge of :func:`plan_tree`: the ``k``-th pair of round ``r``, cluster ``b`` merged into
    ``a`` giving ``out`` (clusters named by node ids: the inputs ``0..n-1``, then one per merge)."""

    r: int
    k: int
    a: int
    b: int
    out: int
    via: dict


def plan_tree(clusters: list[Cluster], edges: list[dict]) -> tuple[list[list[int]], list[list[PlannedMerge]], dict]:
    """:func:`merge_rounds` simulated on placeholders, every merge succeeding: a merged cluster has
    the sessions of both and ``a.keyframes + b.keyframes`` keyframes (the weld appends every keyframe
    of B to A, :func:`vslam.map.append.append_map`, and culling only flags keyframes ``bad``). Returns
    ``(nodes, plan, keyframes)``: per round the node ids of its clusters in order, then the final ones
    (``len(plan) + 1`` lists); per round its merges; each node's keyframe count."""
    nodes = list(range(len(clusters)))
    keyframes = {i: c.keyframes for i, c in enumerate(clusters)}
    names = {i: list(c.sessions) for i, c in enumerate(clusters)}
    states: list[list[int]] = [nodes]
    plan: list[list[PlannedMerge]] = []
    eye = np.eye(4)
    while True:
        placeholders = [Cluster("", dict.fromkeys(names[v], (eye, 0)), keyframes[v]) for v in nodes]
        pairs = plan_round(placeholders, edges)
        if not pairs:
            return states, plan, keyframes
        merges, merged, gone = [], {}, set()
        for k, (i, j, via) in enumerate(pairs):
            a, b = _oriented(placeholders, i, j)
            m = PlannedMerge(len(plan), k, nodes[a], nodes[b], len(clusters) + sum(map(len, plan)) + k, via)
            keyframes[m.out] = keyframes[m.a] + keyframes[m.b]
            names[m.out] = names[m.a] + names[m.b]
            merged[a] = m.out
            gone.add(b)
            merges.append(m)
        nodes = [merged.get(i, v) for i, v in enumerate(nodes) if i not in gone]
        states.append(nodes)
        plan.append(merges)


def _priorities(plan: list[list[PlannedMerge]]) -> list[PlannedMerge]:
    """The merges, most urgent first: the longest chain of merges from each to the end of its tree
    (its bottom level, every merge counted as one), then plan order. Replaying the 16-arc fleet's
    measured merge times on 2 workers: 7.2-7.4 s, against 7.4-7.7 s with the chain weighted by the
    merges' keyframes, 7.3-7.5 s by their seam keyframes, 7.6-7.8 s in plan order (issue #26)."""
    consumer = {n: m for ms in plan for m in ms for n in (m.a, m.b)}
    level: dict[int, int] = {}
    for ms in reversed(plan):
        for m in ms:
            after = consumer.get(m.out)
            level[m.out] = 1 + (level[after.out] if after else 0)
    return sorted((m for ms in plan for m in ms), key=lambda m: (-level[m.out], m.r, m.k))


def _run_plan(ex, plan: list[list[PlannedMerge]], keyframes: dict, real: dict[int, Cluster], edges: list[dict],
              work: Path, config: str | None, overrides: tuple[str, ...]) -> tuple[dict, int | None]:
    """Run the planned merges on ``ex`` as soon as both inputs exist (at most ``ex.slots`` at once);
    ``real`` gains each merged cluster. Once a merge of round ``r`` fails (or its map's keyframes
    differ from the plan's), nothing after round ``r`` is started. Returns ``({(r, k): (rec, step,
    submitted, finished)}, the first such round or None)``."""
    todo = _priorities(plan)
    slots = ex.slots
    running: dict = {}
    done: dict[tuple[int, int], tuple] = {}
    stop: int | None = None
    while True:
        ready = [m for m in todo if (stop is None or m.r <= stop) and m.a in real and m.b in real]
        for m in ready[:max(slots - len(running), 0)]:
            todo.remove(m)
            # the only merge ready: no other can start before a running one ends, so it verifies in a
            # second thread; it asks for that CPU only when nothing runs (else it would wait for it)
            threads = 2 if len(ready) == 1 and slots >= 2 else 1
            args = _task_args(real[m.a], real[m.b], str(work / f"r{m.r}_{m.k}"), edges, config, overrides, threads)
            t0 = time.perf_counter()
            running[ex.submit(merge_task, args, _failed_merge, 1 if running else threads)] = (m, args, t0)
        if not running:
            return done, stop
        task, rec = ex.wait_any(list(running))
        m, args, t0 = running.pop(task)
        new, step = _step(real[m.a], real[m.b], m.via, rec, args[2])
        done[(m.r, m.k)] = (rec, step, t0, time.perf_counter())
        if new is not None:
            real[m.out] = new
            if new.keyframes != keyframes[m.out]:
                log.warning("merge r%d_%d made %d keyframes where the plan said %d: going on round by round",
                            m.r, m.k, new.keyframes, keyframes[m.out])
        if new is None or new.keyframes != keyframes[m.out]:
            stop = m.r if stop is None else min(stop, m.r)


def merge_tree(clusters: list[Cluster], edges: list[dict], ex, work: Path, config: str | None = None,
               overrides: tuple[str, ...] = (), say: Callable[[str], None] = lambda m: None
               ) -> tuple[list[Cluster], list[dict], list[dict]]:
    """:func:`merge_rounds`'s merges without its barrier between rounds: the rounds are planned
    first (:func:`plan_tree`), then each merge runs on the executor ``ex`` (``submit`` /
    ``wait_any`` / ``slots``, :class:`vslam.multisession.executor.TaskExecutor`) as soon as the two
    clusters it needs exist, with the inputs, orientation, seam keyframes and output folder the
    rounds would give it: the same maps whatever the workers or the timing. When a merge of round
    ``r`` fails, the rest of round ``r`` still runs, what was started after it is dropped, and
    :func:`merge_rounds` goes on from the state after round ``r`` (as if it had run from the start).
    Returns the same ``(clusters, failed, rounds)``; a round's ``wall_s`` is here from its first
    merge's start to its last merge's end (rounds overlap in time), ``start_s`` its first merge's
    start after the stage's."""
    t_start = time.perf_counter()
    edges = list(edges)
    work.mkdir(parents=True, exist_ok=True)
    states, plan, keyframes = plan_tree(clusters, edges)
    real = dict(enumerate(clusters))
    done, stop = _run_plan(ex, plan, keyframes, real, edges, work, config, tuple(overrides))
    failed: list[dict] = []
    rounds: list[dict] = []
    for r in range(len(plan) if stop is None else stop + 1):
        recs = [done[(r, m.k)] for m in plan[r]]
        for m, (rec, _, _, _) in zip(plan[r], recs):
            _report(r, real[m.a], real[m.b], rec, edges, failed, say)
        t0, t1 = min(x[2] for x in recs), max(x[3] for x in recs)
        rounds.append({"round": r, "pairs": len(plan[r]), "wall_s": round(t1 - t0, 2),
                       "start_s": round(t0 - t_start, 2), "merges": [x[1] for x in recs]})
    if stop is None:
        return [real[v] for v in states[-1]], failed, rounds
    nodes, merged, gone = states[stop], {}, set()
    for m in plan[stop]:
        if done[(stop, m.k)][0].get("ok"):
            merged[nodes.index(m.a)] = m.out
            gone.add(nodes.index(m.b))
    after = [real[merged.get(i, v)] for i, v in enumerate(nodes) if i not in gone]
    return merge_rounds(after, edges, ex.map, work, config, overrides, say, failed, rounds)
