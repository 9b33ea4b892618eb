"""Descriptor matching: brute-force k-NN (faiss; binary matching in one compiled pass,
:mod:`vslam.features.match_kernels`) with Lowe's ratio test and a mutual check.
Guided matching of projected map points (ORB-SLAM's ``SearchByProjection``) is
:func:`vslam.map.matching.guided_match`.

Hamming distances in NumPy use ``np.bitwise_count`` on XOR'd packed bytes.

Example:
    >>> i1, i2, d = match_descriptors(f1.descriptors, f2.descriptors, binary=True)   # doctest: +SKIP
"""
from __future__ import annotations

import logging

import numpy as np

from vslam.errors import VslamError
from vslam.features.config import MatcherConfig

log = logging.getLogger(__name__)

_EMPTY = (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.float32))


def hamming_pairs(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise Hamming distance between packed binary descriptors ``a[i]`` and ``b[i]``.

    Broadcasts over leading axes: ``a (..., D)``, ``b (..., D)`` uint8 -> ``(...)`` int32.
    With ``D % 8 == 0`` the bytes are viewed as uint64 words (8x fewer popcounts)."""
    a = np.asarray(a, np.uint8)
    b = np.asarray(b, np.uint8)
    if a.shape[-1] % 8 == 0 and a.shape[-1] > 0:
        try:
            a = np.ascontiguousarray(a).view(np.uint64)
            b = np.ascontiguousarray(b).view(np.uint64)
        except ValueError:  # pragma: no cover - unusual strides
            pass
    return np.bitwise_count(np.bitwise_xor(a, b)).sum(axis=-1, dtype=np.int32)


def hamming_matrix(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """All-pairs Hamming distances ``(N, M)`` between ``a (N, D)`` and ``b (M, D)`` uint8 (NumPy
    reference; for big sets use :func:`knn`)."""
    a = np.ascontiguousarray(a, np.uint8)
    b = np.ascontiguousarray(b, np.uint8)
    out = np.empty((len(a), len(b)), np.int32)
    step = max(1, 2_000_000 // max(1, len(b) * a.shape[1] // 8))
    for s in range(0, len(a), step):  # blocks bound the (step, M, D) temporary
        out[s : s + step] = hamming_pairs(a[s : s + step, None, :], b[None, :, :])
    return out


def l2_matrix(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """All-pairs Euclidean distances ``(N, M)`` (float32)."""
    a = np.asarray(a, np.float64)
    b = np.asarray(b, np.float64)
    d2 = (a * a).sum(1)[:, None] + (b * b).sum(1)[None, :] - 2.0 * a @ b.T
    return np.sqrt(np.maximum(d2, 0.0)).astype(np.float32)


def descriptor_distances(a: np.ndarray, b: np.ndarray, binary: bool) -> np.ndarray:
    """Row-wise distances between ``a (..., D)`` and ``b (..., D)``: Hamming bits or L2."""
    if binary:
        return hamming_pairs(a, b).astype(np.float32)
    diff = np.asarray(a, np.float32) - np.asarray(b, np.float32)
    return np.sqrt((diff * diff).sum(axis=-1)).astype(np.float32)


def _faiss():
    import faiss  # imported lazily: it is slow to import

    return faiss


def knn(query: np.ndarray, base: np.ndarray, k: int, binary: bool, num_threads: int = 1,
        use_faiss: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Exact k nearest neighbours of every ``query`` row among ``base`` rows.

    Returns ``(dist (Nq, k) float32, idx (Nq, k) int64)``, sorted by distance; ties are broken
    by the lower base index (so the result is deterministic and equal between faiss and NumPy).
    Missing neighbours (``k > len(base)``) have ``idx = -1`` and ``dist = inf``.
    """
    nq, nb = len(query), len(base)
    dist = np.full((nq, k), np.inf, np.float32)
    idx = np.full((nq, k), -1, np.int64)
    if nq == 0 or nb == 0:
        return dist, idx
    kk = min(k, nb)
    if use_faiss:
        faiss = _faiss()
        faiss.omp_set_num_threads(num_threads)
        if binary:
            base = np.ascontiguousarray(base, np.uint8)
            index = faiss.IndexBinaryFlat(base.shape[1] * 8)
            index.add(base)
            # one extra neighbour lets us re-sort ties by index below
            d, i = index.search(np.ascontiguousarray(query, np.uint8), min(kk + 1, nb))
            d = d.astype(np.float32)
        else:
            base = np.ascontiguousarray(base, np.float32)
            index = faiss.IndexFlatL2(base.shape[1])
            index.add(base)
            d, i = index.search(np.ascontiguousarray(query, np.float32), kk)
            d = np.sqrt(np.maximum(d, 0.0)).astype(np.float32)
        # deterministic tie order: by distance, then base index
        i = i.astype(np.int64)
        order = np.lexsort((i, d), axis=-1)
        d = np.take_along_axis(d, order, 1)[:, :kk]
        i = np.take_along_axis(i, order, 1)[:, :kk]
    else:
        full = hamming_matrix(query, base).astype(np.float32) if binary else l2_matrix(query, base)
        i = np.argsort(full, axis=1, kind="stable")[:, :kk]
        d = np.take_along_axis(full, i, 1)
    dist[:, :kk] = d
    idx[:, :kk] = i
    return dist, idx


def match_descriptors(desc1: np.ndarray, desc2: np.ndarray, binary: bool, ratio: float = 0.8,
                      mutual: bool = True, max_distance: float | None = None,
                      config: MatcherConfig | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Nearest-neighbour matching of ``desc1 (N1, D)`` to ``desc2 (N2, D)``.

    A pair ``(i, j)`` is kept when ``j`` is the nearest neighbour of ``i``, the best distance is
    below ``ratio`` times the second best (Lowe, IJCV 2004, Sec. 7.1), ``j``'s own nearest
    neighbour is ``i`` (``mutual``), and the distance is at most ``max_distance``. With
    ``config`` given, its ``ratio``, ``mutual``, ``max_distance``, threads and backend are used.

    Returns ``(idx1, idx2, distances)``, sorted by ``idx1``; distances are Hamming bits or L2.
    """
    if config is not None:
        ratio, mutual, max_distance = config.ratio, config.mutual, config.max_distance
        threads, use_faiss = config.num_threads, config.use_faiss
    else:
        threads, use_faiss = MatcherConfig.num_threads, True
    if desc1 is None or desc2 is None or len(desc1) == 0 or len(desc2) == 0:
        return _EMPTY
    if desc1.shape[1] != desc2.shape[1]:
        raise VslamError(f"descriptor widths differ: {desc1.shape[1]} vs {desc2.shape[1]}")
    if binary and use_faiss and desc1.shape[1] % 8 == 0:
        # compiled: both directions from one pass over the distance matrix, the same neighbours as knn
        from vslam.features.match_kernels import hamming_nn_mutual

        best, second, nn, back = hamming_nn_mutual(desc1, desc2)
    else:
        dist, idx = knn(desc1, desc2, 2, binary, threads, use_faiss)
        best, second, nn = dist[:, 0], dist[:, 1], idx[:, 0]
        back = knn(desc2, desc1, 1, binary, threads, use_faiss)[1][:, 0] if mutual else None
    keep = nn >= 0
    if ratio < 1.0:
        keep &= best < ratio * second  # inf second-best (one candidate) passes
    if max_distance is not None:
        keep &= best <= max_distance
    if mutual:
        keep &= back[np.maximum(nn, 0)] == np.arange(len(desc1))
    i1 = np.flatnonzero(keep)
    return i1, nn[i1], best[i1]
