"""Which sessions overlap, found without trying every pair (step 2 of :mod:`vslam.multisession`).

1. **One inverted index** (:class:`vslam.map.database.KeyframeDatabase`) holds the bag-of-words
   vector of every keyframe of every session (read from each run's saved ``map/database.npz``; no
   map is loaded); rows are numbered session after session (``owner[row]`` is the session).
2. **Queries.** Each keyframe queries the index once (the inverted index scores only keyframes
   sharing a word; the chance level below reads one dense row per query, O(all keyframes)).
   Per other compatible session (same sensor, same camera), its best raw L1 score minus the
   query's chance level (the median raw score over the other sessions' keyframes, so a scene's
   texture does not vote) is the query's evidence for that pair; its evidence for its best
   session is added to the pair's score (symmetrized over both directions). Each session keeps
   its ``candidates`` best-scoring partners: at most ``N * candidates`` pairs are verified, never
   ``N (N - 1) / 2``.
3. **Verification** (:func:`verify_pair`, one task per candidate pair) is :func:`vslam.merge.merge_maps`'s
   place recognition and acceptance (the 16 keyframes of the smaller map that best match the
   larger by BoW, each verified against its candidates there; the agreeing group; the transform
   over all their seam correspondences), without append or BA: an overlap is an edge with its
   inliers and ``S_a_b`` (SE(3); Sim(3) monocular). The merge itself searches the whole seam again.
"""
from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vslam.errors import MapFormatError, MergeError


@dataclass
class SessionIndexEntry:
    name: str
    folder: Path
    sensor: str
    camera: tuple
    keyframes: list[int]


def _read_session(name: str, folder: Path):
    """``(SessionIndexEntry, KeyframeDatabase)`` from the saved ``map/`` (manifest and database only)."""
    from vslam.map.database import KeyframeDatabase

    root = folder / "map"
    manifest = json.loads((root / "map.json").read_text(encoding="utf-8"))
    if not manifest.get("database"):
        raise MapFormatError(f"{root}: the map has no keyframe database; cannot search overlaps")
    db = KeyframeDatabase.load(root / manifest["database"])
    cam = manifest.get("camera") or {}
    key = tuple(round(float(cam.get(k) or 0.0), 3) for k in ("fx", "fy", "cx", "cy", "width", "height"))
    sensor = (manifest.get("metadata") or {}).get("sensor", "")
    return SessionIndexEntry(name, folder, sensor, key, db.keyframe_ids), db


def candidate_pairs(folders: dict[str, Path], candidates: int = 3) -> tuple[list[dict], dict]:
    """The candidate session pairs (``[{a, b, score}]``, best first) and the search's statistics."""
    from vslam.map.database import KeyframeDatabase

    t0 = time.perf_counter()
    entries, dbs = [], []
    for name, folder in folders.items():
        e, db = _read_session(name, folder)
        entries.append(e)
        dbs.append(db)
    n = len(entries)
    stats = {"sessions": n, "keyframes": 0, "queries": 0, "all_pairs": n * (n - 1) // 2}
    if n < 2:
        return [], {**stats, "candidate_pairs": 0, "search_s": 0.0}
    index = KeyframeDatabase(dbs[0].n_words)
    owner: list[int] = []
    for i, db in enumerate(dbs):
        for k in db.keyframe_ids:
            index.add(len(owner), db.bow(k))
            owner.append(i)
    owner_arr = np.asarray(owner, np.int64)
    compatible = np.array([[a.sensor == b.sensor and a.camera == b.camera for b in entries] for a in entries])
    score = np.zeros((n, n))
    full = np.zeros(len(owner))
    for i, db in enumerate(dbs):
        others = compatible[i].copy()
        others[i] = False
        kf_mask = others[owner_arr]
        if not kf_mask.any():
            continue
        for k in db.keyframe_ids:
            ids, raw, _ = index.raw_scores(db.bow(k), count_common=False)
            stats["queries"] += 1
            full[:] = 0.0
            full[ids] = raw
            chance = float(np.median(full[kf_mask]))  # the query's chance level over the other sessions
            best = np.zeros(n)
            np.maximum.at(best, owner_arr[kf_mask], full[kf_mask])
            excess = np.where(others, best - chance, -np.inf)
            j = int(np.argmax(excess))
            if excess[j] > 0:
                score[i, j] += excess[j]
    stats["keyframes"] = len(owner)
    sym = score + score.T
    pairs: dict[tuple[int, int], float] = {}
    for i in range(n):
        for j in np.argsort(-sym[i], kind="stable")[:candidates]:
            if j != i and sym[i, j] > 0:
                pairs[(min(i, j), max(i, j))] = float(sym[i, j])
    out = [{"a": entries[i].name, "b": entries[j].name, "score": round(s, 4)}
           for (i, j), s in sorted(pairs.items(), key=lambda p: (-p[1], p[0]))]
    stats.update(candidate_pairs=len(out), search_s=round(time.perf_counter() - t0, 3))
    return out, stats


def _best_keyframes(map_a, db_a, map_b, db_b, vocabulary, n: int):
    """B restricted to its ``n`` keyframes whose best BoW score in A is highest (the likely seam)."""
    from types import SimpleNamespace

    scored = []
    for k, kf in map_b.keyframes.items():
        if kf.bad or kf.descriptors is None or kf.descriptors.dtype != np.uint8:
            continue
        bow = db_b.bow(k) if db_b is not None and k in db_b else vocabulary.transform(kf.descriptors)[0]
        _, raw, _ = db_a.raw_scores(bow, count_common=False)
        scored.append((-(float(raw.max()) if raw.size else 0.0), k))
    keep = sorted(k for _, k in sorted(scored)[:n])
    return SimpleNamespace(keyframes={k: map_b.keyframes[k] for k in keep}, points=map_b.points)


def verify_maps(map_a, db_a, map_b, db_b, camera, sensor: str, cfg, max_keyframes: int = 16) -> dict:
    """:func:`vslam.merge.merge_maps`'s place recognition and acceptance (the agreeing group of
    verified matches, the transform over all their correspondences) on B's ``max_keyframes`` best
    BoW matches in A; no append, no BA. Raises :class:`MergeError` when they do not overlap."""
    from vslam.loop.vocabulary import load_default_vocabulary
    from vslam.merge import MergeOptions, agreeing_group, estimate_transform, find_seam

    options = MergeOptions()
    vocabulary = load_default_vocabulary()
    sub_b = _best_keyframes(map_a, db_a, map_b, db_b, vocabulary, max_keyframes)
    matches = find_seam(map_a, db_a, sub_b, db_b, camera, sensor, cfg, vocabulary, options)
    centres = np.stack([k.T_world_cam[:3, 3] for k in map_a.keyframes.values()])
    extent = float(np.linalg.norm(centres - centres.mean(axis=0), axis=1).max())
    tol = options.agree_rel * max(extent, 1e-6) if sensor == "mono" else options.agree_m
    need = cfg.loop.closing.min_inliers_mono if sensor == "mono" else cfg.loop.closing.min_inliers
    group = agreeing_group([m for m in matches if m.ver.n_inliers >= need], sub_b, tol, options.agree_deg)
    if len(group) < options.min_agreeing:
        raise MergeError(f"no overlap: {len(matches)} of {len(sub_b.keyframes)} best-matching keyframes of B were "
                         f"verified in A and at most {len(group)} agree on one alignment ({options.min_agreeing} needed)")
    S, alignment = estimate_transform(group, map_a, sensor)
    return {"inliers": alignment["inliers"], "correspondences": alignment["correspondences"],
            "residual": round(alignment["residual"], 6), "seam_keyframes": len(group),
            "queried_keyframes": len(sub_b.keyframes), "scale": round(float(np.cbrt(np.linalg.det(S[:3, :3]))), 6),
            "transform": "Sim(3)" if sensor == "mono" else "SE(3)",
            "S_a_b": [[round(float(x), 6) for x in row] for row in S]}


def verify_pair(a: str, a_folder: str, b: str, b_folder: str, config: str | None = None,
                overrides: tuple[str, ...] = ()) -> dict:
    """Task: is there a verified overlap between two sessions' maps (:func:`verify_maps`)? Never
    raises; ``verified`` False with ``error`` otherwise. The map with fewer keyframes is B."""
    from vslam.api import resolve_config
    from vslam.map.io import load_run_map

    t0 = time.perf_counter()
    rec: dict = {"a": a, "b": b, "verified": False}
    try:
        map_a, db_a, cam, meta_a = load_run_map(a_folder, f"session {a}", "merge")
        map_b, db_b, _, meta_b = load_run_map(b_folder, f"session {b}", "merge")
        if len(map_b.keyframes) > len(map_a.keyframes):
            (a, a_folder, map_a, db_a, meta_a), (b, b_folder, map_b, db_b, meta_b) = \
                (b, b_folder, map_b, db_b, meta_b), (a, a_folder, map_a, db_a, meta_a)
            rec.update(a=a, b=b)
        if config is None and (Path(a_folder) / "config.yaml").is_file():
            config = str(Path(a_folder) / "config.yaml")
        cfg = resolve_config(config, list(overrides))
        rec.update(verified=True, **verify_maps(map_a, db_a, map_b, db_b, cam, meta_a.get("sensor"), cfg), error=None)
    except MergeError as exc:
        rec["error"] = str(exc)
    except Exception as exc:  # noqa: BLE001 - a pair that cannot be verified is not an edge
        rec["error"] = f"{type(exc).__name__}: {exc}"
    rec["task_s"] = round(time.perf_counter() - t0, 2)
    return rec
