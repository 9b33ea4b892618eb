"""Descriptor matching: brute-force k-NN (faiss) with Lowe's ratio test and a mutual check, and
guided matching of projected map points to keypoints (ORB-SLAM's ``SearchByProjection``).

Hamming distances in NumPy use ``np.bitwise_count`` on XOR'd packed bytes.

Example:
    >>> i1, i2, d = match_descriptors(f1.descriptors, f2.descriptors, binary=True)   # doctest: +SKIP
"""
from __future__ import annotations

import itertools
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
    dist, idx = knn(desc1, desc2, 2, binary, threads, use_faiss)
    best, nn = dist[:, 0], idx[:, 0]
    keep = nn >= 0
    if ratio < 1.0:
        keep &= best < ratio * dist[:, 1]  # inf second-best (one candidate) passes
    if max_distance is not None:
        keep &= best <= max_distance
    if mutual:
        _, back = knn(desc2, desc1, 1, binary, threads, use_faiss)
        keep &= back[np.maximum(nn, 0), 0] == np.arange(len(desc1))
    i1 = np.flatnonzero(keep)
    return i1, nn[i1], best[i1]


def _best_two_per_group(group: np.ndarray, dist: np.ndarray, other: np.ndarray
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """For pairs ``(group, other)`` with distances: per group, the position of the smallest
    distance (ties: lower ``other``) and the second-smallest distance (inf if none).
    Returns ``(groups, best_pos, best_dist, second_dist)``."""
    di = dist.astype(np.int64)
    if len(dist) and np.all(di == dist) and di.min() >= 0:  # Hamming: one unique int64 key
        n_other = int(other.max()) + 1
        o = np.argsort((group * (int(di.max()) + 1) + di) * n_other + other)
    else:
        o = np.lexsort((other, dist, group))
    g = group[o]
    first = np.flatnonzero(np.r_[True, g[1:] != g[:-1]])
    nxt = first + 1
    has2 = np.r_[first[1:], len(g)] > nxt
    second = np.where(has2, dist[o][np.minimum(nxt, len(g) - 1)], np.inf)
    return g[first], o[first], dist[o][first], second


def match_by_projection(proj_uv: np.ndarray, map_desc: np.ndarray, kp_uv: np.ndarray,
                        kp_desc: np.ndarray, radius: float | np.ndarray, binary: bool,
                        max_distance: float | None = None, ratio: float = 1.0,
                        max_candidates: int | None = None, proj_octave: np.ndarray | None = None,
                        kp_octave: np.ndarray | None = None, octave_tolerance: int = 1,
                        kp_available: np.ndarray | None = None,
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Guided matching: for each projected map point, the keypoint with the closest descriptor
    within ``radius`` pixels (ORB-SLAM's ``SearchByProjection``, Mur-Artal et al. 2015, Sec. V-D).

    Args:
        proj_uv: ``(M, 2)`` predicted pixel positions of the map points (NaN rows are skipped).
        map_desc: ``(M, D)`` their descriptors.
        kp_uv, kp_desc: ``(N, 2)``, ``(N, D)`` the frame's keypoints.
        radius: search radius in pixels, scalar or ``(M,)`` (e.g. ``r * scale_factor**level``).
        binary: Hamming (True) or L2 distances.
        max_distance: reject matches whose best distance exceeds this (ORB-SLAM: 100 bits).
        ratio: best < ratio * second best among the candidates (1.0 = off).
        max_candidates: optionally only the nearest ``max_candidates`` keypoints (in pixels) per
            map point are compared; None compares all inside the radius.
        proj_octave, kp_octave, octave_tolerance: if both given, a keypoint is a candidate only
            when its octave is within ``octave_tolerance`` of the predicted one.
        kp_available: optional ``(N,)`` bool; False keypoints (e.g. already matched) are skipped.

    Returns ``(map_idx, kp_idx, dist)``; every keypoint is used at most once (the map point with
    the smallest distance wins), sorted by ``map_idx``. Candidates come from one k-d tree ball
    query (per-point radii); all descriptor distances are computed in one batch.
    """
    from scipy.spatial import cKDTree

    proj_uv = np.asarray(proj_uv, np.float64).reshape(-1, 2)
    kp_uv = np.asarray(kp_uv, np.float64).reshape(-1, 2)
    m, n = len(proj_uv), len(kp_uv)
    if m == 0 or n == 0:
        return _EMPTY
    rad = np.broadcast_to(np.asarray(radius, np.float64), (m,))
    rows = np.flatnonzero(np.isfinite(proj_uv).all(1) & (rad > 0))
    if len(rows) == 0:
        return _EMPTY
    lists = cKDTree(kp_uv).query_ball_point(proj_uv[rows], rad[rows], return_sorted=False)
    cnt = np.fromiter(map(len, lists), np.int64, len(lists))
    if cnt.sum() == 0:
        return _EMPTY
    pm = np.repeat(rows, cnt)  # pair: map point
    pk = np.fromiter(itertools.chain.from_iterable(lists), np.int64, int(cnt.sum()))  # pair: keypoint
    ok = np.ones(len(pm), bool)
    if proj_octave is not None and kp_octave is not None:
        ok &= np.abs(np.asarray(kp_octave)[pk] - np.asarray(proj_octave)[pm]) <= octave_tolerance
    if kp_available is not None:
        ok &= np.asarray(kp_available, bool)[pk]
    pm, pk = pm[ok], pk[ok]
    if max_candidates is not None and len(pm):
        sp = np.linalg.norm(kp_uv[pk] - proj_uv[pm], axis=1)
        o = np.lexsort((pk, sp, pm))
        pm, pk = pm[o], pk[o]
        start = np.flatnonzero(np.r_[True, pm[1:] != pm[:-1]])
        rank = np.arange(len(pm)) - np.repeat(start, np.diff(np.r_[start, len(pm)]))
        pm, pk = pm[rank < max_candidates], pk[rank < max_candidates]
    if len(pm) == 0:
        return _EMPTY
    d = descriptor_distances(np.asarray(map_desc)[pm], np.asarray(kp_desc)[pk], binary)
    groups, pos, best, second = _best_two_per_group(pm, d, pk)
    keep = np.ones(len(groups), bool)
    if max_distance is not None:
        keep &= best <= max_distance
    if ratio < 1.0:
        keep &= best < ratio * second
    map_idx, kp_idx, best = groups[keep], pk[pos[keep]], best[keep].astype(np.float32)
    # each keypoint at most once: smallest distance wins (ties: lower map index)
    o = np.lexsort((map_idx, best))
    _, first = np.unique(kp_idx[o], return_index=True)
    sel = np.sort(o[first])  # back to map_idx order
    return map_idx[sel].astype(np.int64), kp_idx[sel].astype(np.int64), best[sel]
