"""The compiled inverted-index scoring against the SciPy/NumPy code it replaces, to the bit."""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from vslam.map import database_kernels
from vslam.map.database import BowVector, KeyframeDatabase


def _reference(csc, words, values, n_rows):
    sub = csc[:, words]
    mins = np.minimum(sub.data, np.repeat(values, np.diff(sub.indptr)))
    return np.bincount(sub.indices, weights=mins, minlength=n_rows), np.bincount(sub.indices, minlength=n_rows)


def _bow(rng, n_words, size):
    words = np.sort(rng.choice(n_words, size, replace=False)).astype(np.int32)
    values = rng.random(size)
    return BowVector(words, values / values.sum())


def test_column_scores_is_the_sparse_slice_and_bincount():
    database_kernels.warm()
    rng = np.random.default_rng(2)
    n_words, n_rows = 1000, 60
    bows = [_bow(rng, n_words, 300) for _ in range(n_rows)]
    rows = np.repeat(np.arange(n_rows), [len(b.words) for b in bows])
    csc = sp.csc_matrix((np.concatenate([b.values for b in bows]), (rows, np.concatenate([b.words for b in bows]))),
                        shape=(n_rows, n_words))
    csc.sort_indices()
    for _ in range(5):
        q = _bow(rng, n_words, 250)
        got = database_kernels.column_scores(csc.indptr, csc.indices, csc.data, q.words, q.values, n_rows)
        want = _reference(csc, q.words, q.values, n_rows)
        assert np.array_equal(got[0], want[0]) and np.array_equal(got[1], want[1])
        assert got[1].min() > 40 and 0.1 < got[0].max() < 0.6  # every row shares words; L1 scores


def test_database_query_scores_unchanged_through_the_kernel():
    """``raw_scores`` over merged (CSC) and pending keyframes equals the reference sums."""
    rng = np.random.default_rng(6)
    db = KeyframeDatabase(800)
    bows = {i: _bow(rng, 800, 200) for i in range(40)}
    for i, b in bows.items():
        db.add(i, b)
    q = _bow(rng, 800, 200)
    ids, scores, common = db.raw_scores(q)
    dense_q = q.to_dense(800)
    for i, s, c in zip(ids.tolist(), scores, common):
        d = bows[i].to_dense(800)
        assert abs(s - np.minimum(d, dense_q).sum()) < 1e-12
        assert c == np.count_nonzero((d > 0) & (dense_q > 0))
    assert len(ids) == 40 and db._row_ids.size >= 16 and db._pending  # both the CSC block and the pending one
