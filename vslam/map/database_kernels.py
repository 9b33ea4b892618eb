"""Compiled (numba) kernel of :meth:`vslam.map.database.KeyframeDatabase.raw_scores`: the L1 scores
over the inverted index's columns of the query's words, straight from the CSC arrays.

It gives exactly what the SciPy/NumPy code it replaces gave (``sub = csc[:, words]``, then
``np.bincount(sub.indices, weights=np.minimum(sub.data, repeat(values)))``): the same terms added
in the same order (word by word in query order, each column's entries in stored order), so the
same float64 sums, without slicing a sparse matrix per query.
"""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def column_scores(indptr, indices, data, words, values, n_rows):  # pragma: no cover - compiled
    """``(scores (n_rows,) float64, common (n_rows,) int64)``: per row, the sum over the query's
    ``words`` of ``min(data, value)`` and the count of shared words."""
    scores = np.zeros(n_rows)
    common = np.zeros(n_rows, np.int64)
    for j in range(words.shape[0]):
        w = words[j]
        v = values[j]
        for e in range(indptr[w], indptr[w + 1]):
            r = indices[e]
            d = data[e]
            scores[r] += d if d < v else v  # np.minimum (neither is NaN)
            common[r] += 1
    return scores, common


def warm() -> None:
    """Call the kernel once on tiny inputs (loads the cached machine code)."""
    column_scores(np.array([0, 1, 1], np.int32), np.array([0], np.int32), np.array([0.5]),
                  np.array([0, 1], np.int32), np.array([0.3, 0.7]), 1)
