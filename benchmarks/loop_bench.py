"""Place-recognition benchmark: vocabulary load/transform speed, database query speed, real retrieval.

Run: ``python benchmarks/loop_bench.py`` (prints JSON). ``run_loop_bench()`` returns the same dict.
Timings are the best of repeated runs (the machine is shared, medians are noisy).
"""
from __future__ import annotations

import json
import os
import time
from pathlib import Path

import numpy as np

from vslam.map.database import KeyframeDatabase
from vslam.loop.vocabulary import DEFAULT_VOCABULARY_PATH, BowVector, Vocabulary


def _best(fn, repeat: int = 20) -> float:
    fn()
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def _shared_data() -> Path:
    return Path(os.environ.get("VSLAM_SHARED_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))


def _redkitchen_retrieval(voc: Vocabulary) -> dict | None:
    """Keyframes = every 10th frame 0-900 of 7-Scenes redkitchen; query frame 946 (revisit of 248)."""
    import cv2

    from vslam.loop.training import extract_orb

    root = _shared_data() / "7scenes_redkitchen" / "seq-xx"
    if not root.is_dir():
        return None
    bow = {i: voc.transform(extract_orb(cv2.imread(str(root / f"frame-{i:06d}.color.jpg"), 0)))[0]
           for i in list(range(0, 901, 10)) + [946]}
    db = KeyframeDatabase(voc.n_words)
    for i in range(0, 901, 10):
        db.add(i, bow[i])
    top = db.query(bow[946], 3)
    return {"query": 946, "expected": 248, "top3": [[k, round(s, 4)] for k, s in top]}


def run_loop_bench(with_real_data: bool = True) -> dict:
    """Measure the place-recognition building blocks; returns a flat dict of numbers."""
    rng = np.random.default_rng(0)
    t0 = time.perf_counter()
    voc = Vocabulary.load(DEFAULT_VOCABULARY_PATH)
    load_s = time.perf_counter() - t0
    load_s = min(load_s, _best(lambda: Vocabulary.load(DEFAULT_VOCABULARY_PATH), repeat=5))
    desc = rng.integers(0, 256, (1000, 32), dtype=np.uint8)
    transform_s = _best(lambda: voc.transform(desc))

    bows = [voc.transform(rng.integers(0, 256, (1000, 32), dtype=np.uint8))[0] for _ in range(50)]
    keyframes = []
    for k in range(1000):  # 1000 keyframes, vectors recombined from 50 random frames
        a, b = bows[k % 50], bows[(7 * k + 3) % 50]
        words = np.union1d(a.words[: 400 + k % 200], b.words[:300]).astype(np.int32)
        values = rng.random(words.size)
        keyframes.append(BowVector(words, values / values.sum()))
    db = KeyframeDatabase(voc.n_words)
    t0 = time.perf_counter()
    for k, bow in enumerate(keyframes):
        db.add(k, bow)
    add_s = (time.perf_counter() - t0) / len(keyframes)
    query = bows[7]
    query_s = _best(lambda: db.query(query, 10, exclude_ids=range(990, 1000)))
    result = {
        "vocabulary_file": DEFAULT_VOCABULARY_PATH.name,
        "vocabulary_bytes": DEFAULT_VOCABULARY_PATH.stat().st_size,
        "vocabulary_words": voc.n_words,
        "vocabulary_nodes": voc.n_nodes,
        "vocabulary_k": voc.k,
        "vocabulary_L": voc.levels,
        "load_ms": round(load_s * 1e3, 2),
        "transform_1000_ms": round(transform_s * 1e3, 3),
        "query_1000_keyframes_ms": round(query_s * 1e3, 3),
        "add_keyframe_amortized_ms": round(add_s * 1e3, 3),
        "mean_words_per_bow": round(float(np.mean([len(b) for b in bows])), 1),
    }
    if with_real_data:
        result["redkitchen_946"] = _redkitchen_retrieval(voc)
    return result


if __name__ == "__main__":
    print(json.dumps(run_loop_bench(), indent=2))
