"""``vslam map``: sessions tracked as tasks, overlaps found and verified, components merged."""
from __future__ import annotations

import logging
import shutil
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

from vslam.multisession.executor import TaskExecutor
from vslam.multisession.sessions import (SessionSpec, parse_inputs, reusable, reused_record, run_session,
                                        session_prefetches)

log = logging.getLogger(__name__)

#: what ``sessions.json`` keeps of each candidate pair's verification
CANDIDATE_KEYS = ("a", "b", "score", "verified", "inliers", "error", "task_s", "reused")


def _failed_session(args: tuple, message: str) -> dict:
    spec, folder = args[0], args[1]
    return {"name": spec.name, "spec": spec.record(), "folder": folder, "status": "failed", "reused": False,
            "error": message}


def _failed_pair(args: tuple, message: str) -> dict:
    return {"a": args[0], "b": args[2], "verified": False, "error": message}


def _run_sessions(ex: TaskExecutor, specs: list[SessionSpec], root: Path, config: str | None,
                  overrides: tuple[str, ...], say: Callable[[str], None]) -> list[dict]:
    """Every session's record: finished runs reused here, the others run as tasks."""
    records: list[dict | None] = [None] * len(specs)
    todo = []
    for i, s in enumerate(specs):
        stats = reusable(s, root / s.name)
        if stats is not None:
            records[i] = reused_record(s, root / s.name, stats)
        else:
            todo.append(i)
    prefetch = session_prefetches(ex.kind, ex.slots if ex.kind == "ray" else ex.workers, len(todo))
    done = ex.map(run_session, [(specs[i], str(root / specs[i].name), config, overrides, mode)
                                for i, mode in zip(todo, prefetch)], _failed_session)
    for i, r in zip(todo, done):
        records[i] = r
    out: list[dict] = [r for r in records if r is not None]
    for r in out:
        say(f"session {r['name']}: " + (f"failed: {r['error']}" if r["status"] != "ok" else
                                        f"{r.get('keyframes')} keyframes" + (" (reused)" if r["reused"] else "")))
    return out


def _previous(out: Path) -> dict | None:
    """The ``sessions.json`` of an earlier result in ``out`` (``vslam map --map``), or None."""
    import json

    try:
        doc = json.loads((out / "sessions.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return doc if isinstance(doc, dict) and isinstance(doc.get("sessions"), list) else None


def _previous_clusters(prev: dict, reused: set[str], work: Path) -> tuple[list, set[str]]:
    """The components of an earlier result as clusters (their maps copied into ``work``, since the
    outputs are rewritten) when every session of one was reused (its run folder unchanged); and
    their sessions' names."""
    from vslam.multisession.tree_merge import Cluster
    from vslam.outputs import PREVIOUS_NAME

    by = {s["name"]: s for s in prev["sessions"]}
    clusters, names = [], set()
    for i, comp in enumerate(prev.get("component_maps") or []):
        members = comp["sessions"]
        if not all(m in reused and "keyframe_offset" in by.get(m, {}) for m in members):
            continue
        folder = Path(comp["folder"])
        if not (folder / "map" / "map.json").is_file():  # OUT's own outputs: moved aside by open_run_dir
            folder = folder / PREVIOUS_NAME
        if not (folder / "map" / "map.json").is_file():
            continue
        dst = work / f"previous_{i}"
        shutil.copytree(folder / "map", dst / "map")
        if (folder / "config.yaml").is_file():
            shutil.copyfile(folder / "config.yaml", dst / "config.yaml")
        sessions = {m: (np.asarray(by[m]["S_common_session"], float), int(by[m]["keyframe_offset"])) for m in members}
        clusters.append(Cluster(str(dst), sessions, int(comp["keyframes"]), dirty=False))
        names |= set(members)
    return clusters, names


def _previous_verdicts(prev: dict | None, reused: set[str], settings: dict) -> dict[frozenset, dict]:
    """The pair verifications of an earlier result in the same folder, for pairs of two reused
    sessions verified with the same settings: a rerun does not verify them again."""
    if not prev or prev.get("settings") != settings:
        return {}
    out: dict[frozenset, dict] = {}
    for c in prev.get("candidates", []):
        # a pair found not to overlap (a task that crashed has no task_s: it is verified again)
        if c["a"] in reused and c["b"] in reused and not c.get("verified") and c.get("error") and c.get("task_s"):
            out[frozenset((c["a"], c["b"]))] = {k: c.get(k) for k in ("a", "b", "verified", "error", "task_s")}
    for e in prev.get("overlaps", []):
        if e["a"] in reused and e["b"] in reused and e.get("seam"):
            drop = ("in_tree", "merge_error", "score")
            out[frozenset((e["a"], e["b"]))] = {k: v for k, v in e.items() if k not in drop}
    return out


def _verify(ex: TaskExecutor, pairs: list[dict], ok: dict[str, Path], known: dict[frozenset, dict],
            config: str | None, overrides: tuple[str, ...], say: Callable[[str], None]) -> list[dict]:
    """Every candidate pair's verification (``known`` ones reused, the others one task each), with
    its index score."""
    from vslam.multisession.overlap import verify_pair

    todo = [p for p in pairs if frozenset((p["a"], p["b"])) not in known]
    done = iter(ex.map(verify_pair, [(p["a"], str(ok[p["a"]]), p["b"], str(ok[p["b"]]), config, overrides)
                                     for p in todo], _failed_pair))
    verified = [{**known[frozenset((p["a"], p["b"]))], "reused": True} if frozenset((p["a"], p["b"])) in known
                else {**next(done), "reused": False} for p in pairs]
    if len(todo) < len(pairs):
        say(f"{len(pairs) - len(todo)} of {len(pairs)} candidate pairs verified by the earlier run (reused)")
    for p, v in zip(pairs, verified):
        v["score"] = p["score"]
    return verified


def _in_input_order(clusters: list, names: list[str]) -> None:
    """Sessions of each cluster in input order; clusters largest first (ties: first session's order)."""
    for c in clusters:
        c.sessions = dict(sorted(c.sessions.items(), key=lambda kv: names.index(kv[0])))
    clusters.sort(key=lambda c: (-len(c.sessions), names.index(next(iter(c.sessions)))))


def _failed_finalize(args: tuple, message: str) -> dict:
    return {"error": message}


def _previous_edges(prev: dict, old: set[str]) -> list[dict]:
    """The verified overlaps of an earlier result between its kept sessions (not a failed merge's)."""
    return [{k: v for k, v in e.items() if k not in ("in_tree", "merge_error")}
            for e in prev.get("overlaps", []) if e["a"] in old and e["b"] in old and not e.get("merge_error")]


def _finalize_all(ex: TaskExecutor, clusters: list, out: Path, ok: dict[str, Path], edges: list[dict],
                  pose_graph: bool, config: str | None, overrides: tuple[str, ...]) -> tuple[list[Path], list[dict]]:
    """Each component's pose graph, global BA and outputs (one task each; the largest into ``out``,
    the others into ``out/components/<i>``): ``(folders, records)``."""
    from vslam.multisession.global_opt import finalize_task

    folders = [out if i == 0 else out / "components" / str(i) for i in range(len(clusters))]
    final = ex.map(finalize_task, [
        (c.folder, {n: (S.tolist(), off) for n, (S, off) in c.sessions.items()}, {n: str(ok[n]) for n in c.sessions},
         [e for e in edges if {e["a"], e["b"]} <= set(c.sessions)], str(f), str(out / "trajectories"), c.dirty,
         pose_graph, config, overrides) for c, f in zip(clusters, folders)], _failed_finalize)
    return folders, final


def map_sessions(inputs: list[str] | list[SessionSpec], output: str | Path, executor: str = "local",
                 workers: int | None = None, address: str | None = None, config: str | None = None,
                 overrides: tuple[str, ...] = (), sensor: str | None = None, candidates: int = 3,
                 pose_graph: bool = True, incremental: bool = False,
                 on_progress: Callable[[str], None] | None = None) -> dict:
    """Map every session of ``inputs`` into ``output`` (see :mod:`vslam.multisession`); returns
    the content of ``sessions.json``. ``incremental``: ``output`` holds an earlier result whose
    components are kept as they are; only new sessions are tracked, searched, verified and merged
    into them (``vslam map --map``). Otherwise a rerun into the same ``output`` reuses the finished
    sessions and the verifications of pairs of reused sessions made with the same ``config`` and
    ``overrides``. ``pose_graph``: False skips the pose graph over every overlap (the global BA
    still runs), for measuring what it does."""
    from vslam.outputs import open_run_dir
    from vslam.multisession.overlap import candidate_pairs
    from vslam.multisession.tree_merge import Cluster, merge_tree

    say = on_progress or (lambda msg: log.info("%s", msg))
    specs = inputs if inputs and isinstance(inputs[0], SessionSpec) else parse_inputs(list(inputs), sensor)
    out = Path(output)
    config = str(Path(config).resolve()) if config else None
    ex = TaskExecutor(executor, workers, address)
    found = _previous(out)
    prev = found if incremental else None
    settings = {"config": config, "overrides": list(overrides)}
    run_dir = open_run_dir(out, inputs=tuple(Path(s.data) for s in specs))
    t_all = time.perf_counter()
    timing: dict[str, float] = {}
    work = out / "merges"
    try:
        shutil.rmtree(work, ignore_errors=True)
        work.mkdir(parents=True)
        (out / "sessions").mkdir(exist_ok=True)
        with ex:
            t0 = time.perf_counter()
            say(f"tracking {len(specs)} sessions on {ex.description}")
            records = _run_sessions(ex, specs, out / "sessions", config, tuple(overrides), say)
            timing["sessions_s"] = round(time.perf_counter() - t0, 2)
            ok = {r["name"]: Path(r["folder"]) for r in records if r["status"] == "ok"}
            reused = {r["name"] for r in records if r["status"] == "ok" and r["reused"]}
            kept, old = _previous_clusters(prev, reused, work) if prev else ([], set())
            new = (set(ok) - old) if prev else None
            t0 = time.perf_counter()
            pairs, search = candidate_pairs(ok, candidates, new=new)
            timing["overlap_search_s"] = round(time.perf_counter() - t0, 2)
            say(f"overlap search: {search['candidate_pairs']} candidate pairs of {search['all_pairs']} "
                f"({search['queries']} keyframe queries)")
            t0 = time.perf_counter()
            known = _previous_verdicts(found, reused, settings)
            verified = _verify(ex, pairs, ok, known, config, tuple(overrides), say)
            timing["verify_s"] = round(time.perf_counter() - t0, 2)
            edges = [v for v in verified if v["verified"]]
            if prev:  # the earlier result's overlaps still hold (merged ones and their constraints)
                edges += _previous_edges(prev, old)
            names = [s.name for s in specs if s.name in ok]
            t0 = time.perf_counter()
            keyframes = {r["name"]: int(r.get("keyframes") or 0) for r in records}
            clusters = kept + [Cluster(str(ok[n]), {n: (np.eye(4), 0)}, keyframes[n]) for n in names if n not in old]
            clusters, failed_merges, rounds = merge_tree(clusters, edges, ex, work, config, tuple(overrides), say)
            timing["merge_s"] = round(time.perf_counter() - t0, 2)
            _in_input_order(clusters, names)
            for stale in ("trajectories", "components"):
                shutil.rmtree(out / stale, ignore_errors=True)
            t0 = time.perf_counter()
            folders, final = _finalize_all(ex, clusters, out, ok, edges, pose_graph, config, tuple(overrides))
            timing["finalize_s"] = round(time.perf_counter() - t0, 2)
        result = _result(out, clusters, folders, final, records, edges, verified, failed_merges, rounds, say)
        shutil.rmtree(work, ignore_errors=True)
        timing["total_s"] = round(time.perf_counter() - t_all, 2)
        result.update(executor=ex.description, index=search, timing=timing, incremental=bool(prev), settings=settings)
        _write_result(out, result)
    except BaseException as exc:  # stopped or failed: stats.json says so, as a run's
        from vslam.runner import write_error_stats

        write_error_stats(out, exc, {"executor": ex.description, "timing": timing})
        raise
    finally:
        run_dir.release()
    run_dir.finish()
    return result


def _write_result(out: Path, result: dict) -> None:
    """``stats.json`` (executor, index, timing, components) and ``sessions.json``, each atomically."""
    from vslam.outputs import atomic_write_text, strict_json

    atomic_write_text(out / "stats.json", strict_json({k: result[k] for k in ("executor", "index", "timing")}
                                                      | {"components": result["components"]}, indent=1))
    atomic_write_text(out / "sessions.json", strict_json(result, indent=1))


def _result(out: Path, clusters: list, folders: list[Path], final: list[dict], records: list[dict],
            edges: list[dict], verified: list[dict], failed_merges: list[dict], rounds: list[dict],
            say: Callable[[str], None]) -> dict[str, Any]:
    """The content of ``sessions.json`` (see :mod:`vslam.multisession`)."""
    comp_of: dict[str, int] = {}
    comp_info = []
    for i, (c, folder, fin) in enumerate(zip(clusters, folders, final)):
        tree = [m["via"] for m in c.merges]
        root = next(n for n, (_, off) in c.sessions.items() if off == 0)
        comp_info.append({"sessions": c.names, "root": root, "folder": str(folder), "tree": tree,
                          "merges": c.merges, **fin})
        for n in c.sessions:
            comp_of[n] = i
        if fin.get("error"):
            say(f"component {i}: {', '.join(c.names)}: its outputs failed: {fin['error']}")
        else:
            say(f"component {i}: {', '.join(c.names)} -> {folder / 'map'}")
    in_tree = {frozenset(t) for c in comp_info for t in c["tree"]}
    dropped = {frozenset((f["a"], f["b"])): f["error"] for f in failed_merges}
    sessions = []
    for r in records:
        rec = dict(r)
        if r["name"] in comp_of:
            i = comp_of[r["name"]]
            S, off = clusters[i].sessions[r["name"]]
            rec.update(component=i, S_common_session=np.round(S, 6).tolist(), keyframe_offset=int(off))
            if not final[i].get("error"):
                rec["trajectory"] = str(out / "trajectories" / f"{r['name']}.txt")
        sessions.append(rec)
    overlaps = []
    for e in edges:
        key = frozenset((e["a"], e["b"]))
        overlaps.append({**e, "in_tree": key in in_tree, "merge_error": dropped.get(key)})
    return {"sessions": sessions, "overlaps": overlaps,
            "candidates": [{k: v.get(k) for k in CANDIDATE_KEYS} for v in verified],
            "components": [c["sessions"] for c in comp_info], "component_maps": comp_info,
            "merge_rounds": rounds}
