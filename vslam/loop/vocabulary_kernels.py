"""Compiled (numba) descent of descriptors down the vocabulary tree (:meth:`Vocabulary.descend`).

One loop per feature instead of the NumPy version's ``(N, k, W)`` gathers and popcount arrays per
level; the distances are integer Hamming counts and each level keeps the first child of least
distance (as ``argmin``), so the leaves and paths are exactly those of the NumPy code.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from vslam.features.match_kernels import popcount64


@njit(cache=True, nogil=True)
def descend_words(node_words, children, query, levels, path):  # pragma: no cover - compiled
    """Fill ``path (levels + 1, N)`` int32 with each feature's node per level (row 0: the root).

    ``node_words (n, W)`` / ``query (N, W)`` uint64 descriptors, ``children (n, k)`` the descent table
    (a leaf's children are itself, missing children repeat the first)."""
    n_feat, n_w = query.shape
    k = children.shape[1]
    for i in range(n_feat):
        node = 0
        path[0, i] = 0
        for level in range(1, levels + 1):
            best = -1
            best_child = node
            for c in range(k):
                child = children[node, c]
                d = np.int64(0)
                for w in range(n_w):
                    d += popcount64(node_words[child, w] ^ query[i, w])
                if best < 0 or d < best:
                    best = d
                    best_child = child
            node = best_child
            path[level, i] = node
    return path


def descend_numpy(node_words: np.ndarray, children: np.ndarray, query: np.ndarray, levels: int
                  ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`descend_words` in NumPy for packed descriptors of any word width ``query (N, W)``:
    per level one gather of the ``k`` children's descriptors, one XOR and one popcount for all
    features. Returns ``(leaf_nodes (N,), path (levels + 1, N))`` int32."""
    n = query.shape[0]
    node = np.zeros(n, dtype=np.int32)
    path = np.zeros((levels + 1, n), dtype=np.int32)
    rows = np.arange(n)
    for level in range(1, levels + 1):
        kids = children[node]  # (n, k); a leaf's "children" are itself
        bits = np.bitwise_count(node_words[kids] ^ query[:, None, :])  # (n, k, W) uint8
        dist = bits[..., 0].astype(np.uint16)
        for w in range(1, bits.shape[2]):
            dist += bits[..., w]
        node = kids[rows, dist.argmin(axis=1)]
        path[level] = node
    return node, path


def warm() -> None:
    """Compile / load the kernels once on tiny inputs."""
    words = np.zeros((3, 4), np.uint64)
    children = np.array([[1, 2], [1, 1], [2, 2]], np.int32)
    descend_words(words, children, np.ones((2, 4), np.uint64), 2, np.zeros((3, 2), np.int32))
