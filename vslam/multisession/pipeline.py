"""``vslam map``: sessions tracked as tasks, overlaps found and verified, components merged."""
from __future__ import annotations

import logging
import shutil
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

from vslam.multisession.executor import TaskExecutor
from vslam.multisession.graph import components, spanning_tree
from vslam.multisession.sessions import SessionSpec, parse_inputs, reusable, reused_record, run_session

log = logging.getLogger(__name__)


def _failed_session(args: tuple, message: str) -> dict:
    spec, folder = args[0], args[1]
    return {"name": spec.name, "spec": spec.record(), "folder": folder, "status": "failed", "reused": False,
            "error": message}


def _failed_pair(args: tuple, message: str) -> dict:
    return {"a": args[0], "b": args[2], "verified": False, "error": message}


def _run_sessions(ex: TaskExecutor, specs: list[SessionSpec], root: Path, config: str | None,
                  overrides: tuple[str, ...]) -> list[dict]:
    """Every session's record: finished runs reused here, the others run as tasks."""
    records: list[dict | None] = [None] * len(specs)
    todo = []
    for i, s in enumerate(specs):
        stats = reusable(s, root / s.name)
        if stats is not None:
            records[i] = reused_record(s, root / s.name, stats)
        else:
            todo.append(i)
    done = ex.map(run_session, [(specs[i], str(root / specs[i].name), config, overrides) for i in todo],
                  _failed_session)
    for i, r in zip(todo, done):
        records[i] = r
    return records  # type: ignore[return-value]


def _merge_all(names: list[str], folders: dict[str, Path], edges: list[dict], keyframes: dict[str, int],
               config: str | None, overrides: tuple[str, ...]) -> tuple[list, list[dict]]:
    """Every component merged along its spanning tree; a tree edge whose merge fails is dropped
    (recorded in ``failed``) and its component split again. Returns ``(component maps, failed)``."""
    from vslam.multisession.merging import TreeMergeFailed, merge_component

    edges = list(edges)
    failed: list[dict] = []
    queue = components(names, edges)
    done = []
    while queue:
        group = queue.pop(0)
        sub = [e for e in edges if e["a"] in group and e["b"] in group]
        tree = spanning_tree(group, sub)
        try:
            comp = merge_component(group, folders, tree, keyframes, config, overrides)
        except TreeMergeFailed as exc:
            bad = next(e for e in tree if {e["a"], e["b"]} == {exc.parent, exc.child})
            edges.remove(bad)
            failed.append({"a": bad["a"], "b": bad["b"], "error": exc.message})
            log.warning("%s; that overlap is dropped", exc)
            queue = components(group, [e for e in edges if e["a"] in group and e["b"] in group]) + queue
            continue
        comp.tree = tree  # type: ignore[attr-defined]
        done.append(comp)
    done.sort(key=lambda c: (-len(c.names), names.index(c.names[0])))
    return done, failed


def map_sessions(inputs: list[str] | list[SessionSpec], output: str | Path, executor: str = "local",
                 workers: int | None = None, address: str | None = None, config: str | None = None,
                 overrides: tuple[str, ...] = (), sensor: str | None = None, candidates: int = 3,
                 on_progress: Callable[[str], None] | None = None) -> dict:
    """Map every session of ``inputs`` into ``output`` (see :mod:`vslam.multisession`); returns
    the content of ``sessions.json``."""
    from vslam.outputs import atomic_write_text, open_run_dir, strict_json
    from vslam.multisession.overlap import candidate_pairs, verify_pair

    say = on_progress or (lambda msg: log.info("%s", msg))
    specs = inputs if inputs and isinstance(inputs[0], SessionSpec) else parse_inputs(list(inputs), sensor)
    out = Path(output)
    config = str(Path(config).resolve()) if config else None
    ex = TaskExecutor(executor, workers, address)
    run_dir = open_run_dir(out, inputs=tuple(Path(s.data) for s in specs))
    t_all = time.perf_counter()
    timing: dict[str, float] = {}
    try:
        for stale in ("trajectories", "components"):
            shutil.rmtree(out / stale, ignore_errors=True)
        (out / "sessions").mkdir(exist_ok=True)
        with ex:
            t0 = time.perf_counter()
            say(f"tracking {len(specs)} sessions on {ex.description}")
            records = _run_sessions(ex, specs, out / "sessions", config, tuple(overrides))
            timing["sessions_s"] = round(time.perf_counter() - t0, 2)
            ok = {r["name"]: Path(r["folder"]) for r in records if r["status"] == "ok"}
            for r in records:
                say(f"session {r['name']}: " + (f"failed: {r['error']}" if r["status"] != "ok" else
                                                f"{r.get('keyframes')} keyframes" + (" (reused)" if r["reused"] else "")))
            t0 = time.perf_counter()
            pairs, search = candidate_pairs(ok, candidates)
            timing["overlap_search_s"] = round(time.perf_counter() - t0, 2)
            say(f"overlap search: {search['candidate_pairs']} candidate pairs of {search['all_pairs']} "
                f"({search['queries']} keyframe queries)")
            t0 = time.perf_counter()
            verified = ex.map(verify_pair, [(p["a"], str(ok[p["a"]]), p["b"], str(ok[p["b"]]), config,
                                             tuple(overrides)) for p in pairs], _failed_pair)
            timing["verify_s"] = round(time.perf_counter() - t0, 2)
        for p, v in zip(pairs, verified):
            v["score"] = p["score"]
        edges = [v for v in verified if v["verified"]]
        names = [s.name for s in specs if s.name in ok]
        t0 = time.perf_counter()
        keyframes = {r["name"]: int(r.get("keyframes") or 0) for r in records}
        comps, failed_merges = _merge_all(names, ok, edges, keyframes, config, tuple(overrides))
        result = _write_outputs(out, comps, ok, records, edges, verified, failed_merges, say)
        timing["merge_s"] = round(time.perf_counter() - t0, 2)
        timing["total_s"] = round(time.perf_counter() - t_all, 2)
        result.update(executor=ex.description, index=search, timing=timing)
        atomic_write_text(out / "stats.json", strict_json({k: result[k] for k in ("executor", "index", "timing")}
                                                          | {"components": result["components"]}, indent=1))
        atomic_write_text(out / "sessions.json", strict_json(result, indent=1))
    except BaseException as exc:  # stopped or failed: stats.json says so, as a run's
        from vslam.runner import write_error_stats

        write_error_stats(out, exc, {"executor": ex.description, "timing": timing})
        raise
    finally:
        run_dir.release()
    run_dir.finish()
    return result


def _write_outputs(out: Path, comps: list, folders: dict[str, Path], records: list[dict], edges: list[dict],
                   verified: list[dict], failed_merges: list[dict], say: Callable[[str], None]) -> dict[str, Any]:
    from vslam.multisession.merging import session_trajectory
    from vslam.outputs import atomic_path
    from vslam.reconstruction.map_outputs import write_map_outputs
    from vslam.trajectory import write_tum

    comp_of: dict[str, int] = {}
    comp_info = []
    (out / "trajectories").mkdir(exist_ok=True)
    for i, comp in enumerate(comps):
        folder = out if i == 0 else out / "components" / str(i)
        folder.mkdir(parents=True, exist_ok=True)
        write_map_outputs(folder, comp.map, camera=comp.camera, database=comp.database, metadata=comp.metadata)
        if (folders[comp.root] / "config.yaml").is_file():  # `vslam localize` detects features as the runs did
            with atomic_path(folder / "config.yaml") as tmp:
                shutil.copyfile(folders[comp.root] / "config.yaml", tmp)
        for n in comp.names:
            comp_of[n] = i
            with atomic_path(out / "trajectories" / f"{n}.txt") as tmp:
                write_tum(tmp, session_trajectory(comp, n, folders[n]))
        comp_info.append({"sessions": comp.names, "root": comp.root, "folder": str(folder),
                          "keyframes": len(comp.map.keyframes), "points": int(comp.map.points.n_alive),
                          "tree": [[e["a"], e["b"]] for e in comp.tree], "merges": comp.merges})
        say(f"component {i}: {', '.join(comp.names)} -> {folder / 'map'}")
    in_tree = {frozenset((a, b)) for c in comp_info for a, b in c["tree"]}
    dropped = {frozenset((f["a"], f["b"])): f["error"] for f in failed_merges}
    sessions = []
    for r in records:
        rec = {k: v for k, v in r.items() if k != "folder"}
        rec["folder"] = r["folder"]
        if r["name"] in comp_of:
            c = comps[comp_of[r["name"]]]
            rec["component"] = comp_of[r["name"]]
            rec["S_common_session"] = np.round(c.placements[r["name"]].S, 6).tolist()
            rec["trajectory"] = str(out / "trajectories" / f"{r['name']}.txt")
        sessions.append(rec)
    overlaps = []
    for e in edges:
        key = frozenset((e["a"], e["b"]))
        overlaps.append({**e, "in_tree": key in in_tree, "merge_error": dropped.get(key)})
    return {"sessions": sessions, "overlaps": overlaps,
            "candidates": [{k: v.get(k) for k in ("a", "b", "score", "verified", "inliers", "error", "task_s")}
                           for v in verified],
            "components": [c["sessions"] for c in comp_info], "component_maps": comp_info}
