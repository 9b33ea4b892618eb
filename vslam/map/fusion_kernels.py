"""Compiled (numba) kernels of :func:`vslam.map.fusion.apply_remap`.

They give exactly what the NumPy expressions they replace gave: :func:`follow_chains` the
``remap[moved] = remap[remap[moved]]`` rounds (each round reads every entry before it writes, as
the vectorized assignment), :func:`remap_ids` the gather ``remap[point_ids]`` (``-1`` -> ``remap[-1]``),
one call per keyframe without NumPy's fancy-indexing set-up.
"""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def follow_chains(remap, rounds):  # pragma: no cover - compiled
    """In place: ``moved = flatnonzero(remap[:-1] != arange(len(remap) - 1))``, then ``rounds`` times
    ``remap[moved] = remap[remap[moved]]``."""
    n = remap.shape[0] - 1
    count = 0
    for i in range(n):
        if remap[i] != i:
            count += 1
    moved = np.empty(count, np.int64)
    j = 0
    for i in range(n):
        if remap[i] != i:
            moved[j] = i
            j += 1
    nxt = np.empty(count, remap.dtype)
    for _ in range(rounds):
        for j in range(count):
            r = remap[moved[j]]
            nxt[j] = remap[r if r >= 0 else r + remap.shape[0]]
        for j in range(count):
            remap[moved[j]] = nxt[j]


@njit(cache=True, nogil=True)
def remap_ids(remap, point_ids):  # pragma: no cover - compiled
    """``remap[point_ids]`` as a new array (negative ids index from the end, as NumPy)."""
    out = np.empty(point_ids.shape[0], remap.dtype)
    n = remap.shape[0]
    for i in range(point_ids.shape[0]):
        p = point_ids[i]
        out[i] = remap[p if p >= 0 else p + n]
    return out


def warm() -> None:
    """Call each kernel once on tiny inputs (loads the cached machine code)."""
    remap = np.array([1, 1, -1], np.int64)
    follow_chains(remap, 2)
    remap_ids(remap, np.array([0, -1], np.int64))
