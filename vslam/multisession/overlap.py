"""Which sessions overlap, found without trying every pair (step 2 of :mod:`vslam.multisession`).

1. **One inverted index** (:class:`PostingIndex`, :func:`build_index`) over the bag-of-words vector
   of every keyframe of every session (read from each run's saved ``map/database.npz``; no map is
   loaded): one posting list per word (the keyframes holding it, with their weights); rows are
   numbered session after session (``owner[row]`` is the session).
2. **Queries** (:func:`candidate_pairs`). Each keyframe queries the index once (:func:`raw_scores`):
   only the posting lists of its own words are visited, and of those only the shortest ones (the
   words most distinctive in this index) up to ``budget`` entries in all, so one query's work is
   bounded whatever the number of sessions. (The embedded 10^4-word vocabulary puts ~1550 words in
   a keyframe and each word in ~40 % of the keyframes: a query over all its words visits ~0.4 x
   1550 x K entries, 110 k at K = 264 keyframes, i.e. K^2 over all queries.) Everything after works
   on the hits alone: the query's chance level is the median score over the other compatible
   sessions' keyframes (same sensor and camera; those sharing none of the words count as 0, so the
   median is taken from the hits by rank, :func:`median_with_zeros`), so a scene's texture does not
   vote; the ``top_k`` best other sessions among the hits (by their best keyframe) each get their
   best score minus the chance level as the query's evidence for that pair (symmetrized over both
   directions). Each session keeps its ``candidates`` best-scoring partners: at most
   ``N * candidates`` pairs are verified, never ``N (N - 1) / 2``. With ``new`` (``vslam map
   --map``) only the new sessions' keyframes query, and only pairs with a new session are
   candidates.
3. **Verification** (:func:`verify_pair`, one task per candidate pair) is :func:`vslam.merge.merge_maps`'s
   place recognition and acceptance (the 16 keyframes of the smaller map that best match the
   larger by BoW, each verified against its candidates there; the agreeing group; the transform
   over all their seam correspondences), without append or BA: an overlap is an edge with its
   inliers, ``S_a_b`` (SE(3); Sim(3) monocular) and its ``seam`` (``[a_kf, b_kf, inliers]`` of the
   agreeing keyframes, the pose-graph constraints of :mod:`vslam.multisession.global_opt`).

Measured (benchmarks/RESULTS.md, issue #26): the budget of 4096 entries, on the 32-arc fleet,
keeps every true overlap chain connected and puts more true overlaps among the candidates than the
full score (42 of 57 vs 36 of 54: the rare words are the distinctive ones); the search grows
linearly in the keyframes (K log K for the hits' sort) where the full score grew as K^2.
"""
from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vslam.errors import MapFormatError, MergeError

#: A's bag-of-words candidates verified per B keyframe in a pair verification (``vslam merge``
#: tries 3). B's keyframes are already its best matches in A, so the third rarely wins. Measured
#: (benchmarks/RESULTS.md, round 5), 3 -> 2: the fleet of 16, the same 25 overlaps with the same
#: inliers, verification 15.0 -> 10.9 s sequential; 7-Scenes in 5 sessions, the same 8 overlaps
#: (inliers within 2 %), 6.1 -> 4.3 s with 2 workers, ATE 0.0463 -> 0.0465 m.
PAIR_CANDIDATES = 2


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


def median_with_zeros(values: np.ndarray, n_total: int) -> float:
    """``np.median`` of ``values`` padded with ``n_total - len(values)`` zeros (the keyframes a query
    shares no word with), from the non-negative ``values`` alone: ``O(len(values))``.

    >>> median_with_zeros(np.array([0.3, 0.1, 0.2]), 4), float(np.median([0.3, 0.1, 0.2, 0.0]))
    (0.15, 0.15)
    """
    zeros = n_total - values.size
    if n_total <= 0:
        return 0.0
    ranks = [(n_total - 1) // 2, n_total // 2]  # the middle one (odd) or two (even) of the sorted padded row
    picked = []
    need = sorted({r - zeros for r in ranks if r >= zeros})
    part = np.partition(values, need) if need else values
    for r in ranks:
        picked.append(0.0 if r < zeros else float(part[r - zeros]))
    return 0.5 * (picked[0] + picked[1])


@dataclass
class PostingIndex:
    """The inverted index of every session's keyframes: CSC arrays of the ``(keyframes, words)``
    BoW matrix (``indptr[w]:indptr[w + 1]`` is word ``w``'s posting list: ``rows`` and ``values``),
    ``owner[row]`` the session of each row."""

    indptr: np.ndarray
    rows: np.ndarray
    values: np.ndarray
    owner: np.ndarray


def build_index(dbs: list) -> PostingIndex:
    """One inverted index over the keyframes of every session's database, rows numbered session
    after session."""
    import scipy.sparse as sp

    bows = [db.bow(k) for db in dbs for k in db.keyframe_ids]
    owner = np.repeat(np.arange(len(dbs)), [len(db.keyframe_ids) for db in dbs]).astype(np.int64)
    lengths = np.array([len(b) for b in bows], np.int64)
    rows = np.repeat(np.arange(len(bows)), lengths)
    cols = np.concatenate([b.words for b in bows]) if bows else np.zeros(0, np.int64)
    vals = np.concatenate([b.values for b in bows]) if bows else np.zeros(0)
    csc = sp.csc_matrix((vals, (rows, cols)), shape=(len(bows), dbs[0].n_words))
    csc.sort_indices()
    return PostingIndex(csc.indptr.astype(np.int64), csc.indices.astype(np.int64), csc.data, owner)


def raw_scores(index: PostingIndex, bow, budget: int) -> tuple[np.ndarray, np.ndarray]:
    """``(rows, scores)``: the L1 score ``sum_w min(q_w, d_w)`` (Galvez-Lopez & Tardos 2012, eq. 3, as
    :meth:`KeyframeDatabase.raw_scores`) of every keyframe sharing a word with the query, summed over
    the query's words with the shortest posting lists (the most distinctive in this index, its idf)
    up to ``budget`` posting entries in all (at least one word): a query's work is bounded, whatever
    the index's size. With every word under the budget it is the full score."""
    w = np.asarray(bow.words, np.int64)
    if w.size == 0:
        return np.zeros(0, np.int64), np.zeros(0)
    df = index.indptr[w + 1] - index.indptr[w]
    order = np.argsort(df, kind="stable")
    take = order[: max(1, int(np.searchsorted(np.cumsum(df[order]), budget, side="right")))]
    w, q, lens = w[take], np.asarray(bow.values)[take], df[take]
    total = int(lens.sum())
    if total == 0:
        return np.zeros(0, np.int64), np.zeros(0)
    # every (posting entry, query weight) of the chosen words, flattened without a Python loop
    starts = np.repeat(index.indptr[w] - np.concatenate(([0], np.cumsum(lens)[:-1])), lens)
    at = starts + np.arange(total)
    hits, inv = np.unique(index.rows[at], return_inverse=True)
    return hits, np.bincount(inv, weights=np.minimum(np.repeat(q, lens), index.values[at]))


def query_evidence(index: PostingIndex, bow, others: np.ndarray, n_others: int, top_k: int = 1,
                   budget: int = 4096) -> list[tuple[int, float]]:
    """One keyframe's evidence: ``[(session, best raw score - chance level)]`` for the ``top_k``
    other sessions (``others[j]`` True: compatible, not the query's own) whose best keyframe scores
    highest, when above the chance level (the median over the ``n_others`` keyframes of those
    sessions); only the index's hits are touched."""
    ids, raw = raw_scores(index, bow, budget)
    owner = index.owner
    keep = others[owner[ids]]
    ids, raw = ids[keep], raw[keep]
    if raw.size == 0:
        return []
    chance = median_with_zeros(raw, n_others)
    who = owner[ids]
    if top_k == 1:
        b = int(np.argmax(raw))
        return [(int(who[b]), float(raw[b]) - chance)] if raw[b] > chance else []
    order = np.argsort(-raw, kind="stable")
    out, seen = [], set()
    for r in order:
        if raw[r] <= chance or len(out) == top_k:
            break
        j = int(who[r])
        if j not in seen:
            seen.add(j)
            out.append((j, float(raw[r]) - chance))
    return out


def candidate_pairs(folders: dict[str, Path], candidates: int = 3, new: set[str] | None = None,
                    top_k: int = 1, budget: int = 4096) -> tuple[list[dict], dict]:
    """The candidate session pairs (``[{a, b, score}]``, best first) and the search's statistics;
    ``new``: only these sessions query, only pairs with one of them are candidates (module docstring)."""
    t0 = time.perf_counter()
    entries, dbs = [], []
    for name, folder in folders.items():
        e, db = _read_session(name, folder)
        entries.append(e)
        dbs.append(db)
    n = len(entries)
    is_new = np.array([new is None or e.name in new for e in entries], bool)
    all_pairs = n * (n - 1) // 2 - (0 if new is None else int((~is_new).sum() * ((~is_new).sum() - 1) // 2))
    stats = {"sessions": n, "keyframes": 0, "queries": 0, "all_pairs": all_pairs}
    if n < 2 or not is_new.any():
        return [], {**stats, "candidate_pairs": 0, "search_s": 0.0, "read_s": 0.0}
    t_read = time.perf_counter() - t0
    index = build_index(dbs)
    owner = index.owner
    stats["keyframes"] = len(owner)
    sizes = np.bincount(owner, minlength=n)
    compatible = np.array([[a.sensor == b.sensor and a.camera == b.camera for b in entries] for a in entries])
    score = np.zeros((n, n))
    for i, db in enumerate(dbs):
        others = compatible[i].copy()
        others[i] = False
        if not is_new[i] or not others.any():
            continue
        n_others = int(sizes[others].sum())
        for k in db.keyframe_ids:
            stats["queries"] += 1
            for j, ev in query_evidence(index, db.bow(k), others, n_others, top_k, budget):
                score[i, j] += ev
    sym = score + score.T
    pairs: dict[tuple[int, int], float] = {}
    for i in range(n):
        for j in np.argsort(-sym[i], kind="stable")[:candidates]:
            if j != i and sym[i, j] > 0 and (is_new[i] or is_new[j]):
                pairs[(min(i, j), max(i, j))] = float(sym[i, j])
    out = [{"a": entries[i].name, "b": entries[j].name, "score": round(s, 4)}
           for (i, j), s in sorted(pairs.items(), key=lambda p: (-p[1], p[0]))]
    stats.update(candidate_pairs=len(out), search_s=round(time.perf_counter() - t0, 3), read_s=round(t_read, 3))
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
    BoW matches in A, each verified against its :data:`PAIR_CANDIDATES` best candidates in A; no
    append, no BA. Raises :class:`MergeError` when they do not overlap."""
    from vslam.loop.vocabulary import load_default_vocabulary
    from vslam.merge import MergeOptions, agreeing_group, estimate_transform, find_seam

    options = MergeOptions(candidates=PAIR_CANDIDATES)
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
            "seam": [[int(m.a_kf), int(m.b_kf), int(m.ver.n_inliers)] for m in group],
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
