"""Inverted-index keyframe database: exact L1 scores, normalization, erase, save/load (real retrieval
with the vocabulary: tests/loop/test_database_retrieval.py)."""
from __future__ import annotations

import time

import numpy as np
import pytest

from vslam.errors import MapFormatError
from vslam.loop.vocabulary import l1_score
from vslam.map.config import DatabaseConfig
from vslam.map.database import BowVector, KeyframeDatabase

N_WORDS = 10_000


def random_bow(rng, n_words: int = N_WORDS, size: int = 600) -> BowVector:
    """A BoW vector with Zipf-like word frequencies, as real images have."""
    words = np.unique(np.minimum(rng.zipf(1.3, size * 2), n_words) - 1)[:size]
    words = np.unique(np.concatenate([words, rng.choice(n_words, size // 2, replace=False)]))
    values = rng.random(words.size)
    return BowVector(words.astype(np.int32), values / values.sum())


def brute_force(db_bows: dict, query: BowVector) -> dict:
    return {k: l1_score(query, b) for k, b in db_bows.items()}


@pytest.mark.parametrize("merge_every", [1, 7, 1000])
def test_raw_scores_equal_brute_force_l1(merge_every):
    rng = np.random.default_rng(merge_every)
    db = KeyframeDatabase(N_WORDS, DatabaseConfig(merge_every=merge_every))
    bows = {int(k): random_bow(rng) for k in rng.choice(10_000, 40, replace=False)}
    for k, b in bows.items():
        db.add(k, b)
    query = random_bow(rng)
    ids, scores, common = db.raw_scores(query)
    expected = brute_force(bows, query)
    assert sorted(ids.tolist()) == sorted(k for k, s in expected.items() if s > 0)
    for k, s, c in zip(ids, scores, common):
        assert s == pytest.approx(expected[int(k)], abs=1e-12)
        assert c == np.intersect1d(bows[int(k)].words, query.words).size


def test_query_excludes_normalizes_and_sorts():
    rng = np.random.default_rng(11)
    cfg = DatabaseConfig(merge_every=5, min_baseline_keyframes=4)
    db = KeyframeDatabase(N_WORDS, cfg)
    bows = {k: random_bow(rng) for k in range(30)}
    for k, b in bows.items():
        db.add(k, b)
    query = random_bow(rng)
    raw = brute_force(bows, query)
    exclude = {3, 4, 5, 999}
    result = db.query(query, max_results=5, exclude_ids=exclude)
    others = np.array([raw[k] for k in bows if k not in exclude])
    baseline, reference = np.median(others), max(raw[k] for k in (3, 4, 5))
    expected = sorted(((k, (raw[k] - baseline) / (reference - baseline)) for k in bows if k not in exclude),
                      key=lambda t: -t[1])[:5]
    assert [k for k, _ in result] == [k for k, _ in expected]
    np.testing.assert_allclose([s for _, s in result], [s for _, s in expected], rtol=1e-9)
    # plain DBoW2 ratio, and raw scores when nothing is excluded
    plain = KeyframeDatabase(N_WORDS, DatabaseConfig(subtract_baseline=False))
    for k, b in bows.items():
        plain.add(k, b)
    top = plain.query(query, 1, exclude_ids=exclude)[0]
    assert top[1] == pytest.approx(raw[top[0]] / reference)
    assert plain.query(query, 1)[0][1] == pytest.approx(max(raw.values()))
    # min_score filters on the normalized score
    assert all(s >= 0.2 for _, s in db.query(query, 30, exclude_ids=exclude, min_score=0.2))


def test_erase_replace_and_merge():
    rng = np.random.default_rng(12)
    db = KeyframeDatabase(N_WORDS, DatabaseConfig(merge_every=4))
    bows = {k: random_bow(rng) for k in range(10)}
    for k, b in bows.items():
        db.add(k, b)
    db.erase(2)   # merged row
    db.erase(9)   # pending row
    db.erase(123)  # unknown: ignored
    assert len(db) == 8 and 2 not in db and 9 not in db
    ids = set(db.raw_scores(bows[2])[0].tolist())
    assert ids == set(bows) - {2, 9}
    db.add(5, bows[2])  # replace keyframe 5's vector
    top = db.query(bows[2], 1)[0]
    assert top[0] == 5 and top[1] == pytest.approx(1.0)


def test_save_load_round_trip(tmp_path):
    rng = np.random.default_rng(13)
    db = KeyframeDatabase(N_WORDS, DatabaseConfig(merge_every=3))
    for k in range(20):
        db.add(k * 7, random_bow(rng))
    db.erase(14)
    path = db.save(tmp_path / "db.npz")
    back = KeyframeDatabase.load(path)
    assert back.keyframe_ids == db.keyframe_ids and back.n_words == N_WORDS
    for k in db.keyframe_ids:
        np.testing.assert_array_equal(back.bow(k).words, db.bow(k).words)
        np.testing.assert_array_equal(back.bow(k).values, db.bow(k).values)
    q = random_bow(rng)
    assert back.query(q, 5, exclude_ids=[0, 7]) == db.query(q, 5, exclude_ids=[0, 7])
    (tmp_path / "bad.npz").write_bytes(b"PK\x03\x04 truncated")
    with pytest.raises(MapFormatError):
        KeyframeDatabase.load(tmp_path / "bad.npz")


def test_query_over_1000_keyframes_is_fast():
    rng = np.random.default_rng(14)
    db = KeyframeDatabase(N_WORDS)
    bows = [random_bow(rng, size=800) for _ in range(100)]
    for k in range(1000):
        db.add(k, bows[k % 100])
    query = random_bow(rng, size=800)
    db.query(query, 10, exclude_ids=range(990, 1000))
    best = np.inf
    for _ in range(15):
        t0 = time.perf_counter()
        db.query(query, 10, exclude_ids=range(990, 1000))
        best = min(best, time.perf_counter() - t0)
    assert best < 0.010, f"query over 1000 keyframes took {best * 1e3:.1f} ms (target 5 ms)"
