"""Compiled (numba) Hamming nearest neighbours for :func:`vslam.features.match.match_descriptors`.

One pass over the ``(N1, N2)`` distance matrix gives what two brute-force k-NN searches (faiss
``IndexBinaryFlat``, forward with two neighbours and backward with one for the mutual check)
computed: each query row's best and second-best distance and its nearest base row, and each base
row's nearest query row. Distances are exact integer bit counts and ties go to the lower index,
the order :func:`vslam.features.match.knn` documents, so the matches are exactly the same; the
matrix is computed once instead of twice and nothing is allocated per pair.
"""
from __future__ import annotations

import numpy as np
from numba import njit

_M1 = np.uint64(0x5555555555555555)
_M2 = np.uint64(0x3333333333333333)
_M4 = np.uint64(0x0F0F0F0F0F0F0F0F)
_H01 = np.uint64(0x0101010101010101)


@njit(cache=True, nogil=True)
def popcount64(x):  # pragma: no cover - compiled
    """Set bits of a uint64 (SWAR popcount; LLVM emits the popcnt instruction for it)."""
    x = x - ((x >> np.uint64(1)) & _M1)
    x = (x & _M2) + ((x >> np.uint64(2)) & _M2)
    x = (x + (x >> np.uint64(4))) & _M4
    return np.int64((x * _H01) >> np.uint64(56))


@njit(cache=True, nogil=True)
def nn2_mutual(a, b, best, second, nn, back):  # pragma: no cover - compiled
    """For ``a (N1, W)`` and ``b (N2, W)`` uint64 packed descriptors fill ``best``, ``second``
    (N1,) int64 (second: -1 when ``N2 == 1``), ``nn (N1,)`` (the lowest index of least distance)
    and ``back (N2,)`` (each ``b`` row's nearest ``a`` row, lowest index on ties)."""
    na, w = a.shape
    nb = b.shape[0]
    big = np.int64(1) << 40
    back_d = np.full(nb, big, np.int64)
    for j in range(nb):
        back[j] = -1
    for i in range(na):
        b0 = big
        b1 = big
        n0 = -1
        for j in range(nb):
            d = np.int64(0)
            for q in range(w):
                d += popcount64(a[i, q] ^ b[j, q])
            if d < b0:
                b1 = b0
                b0 = d
                n0 = j
            elif d < b1:
                b1 = d
            if d < back_d[j]:
                back_d[j] = d
                back[j] = i
        best[i] = b0
        second[i] = b1 if b1 < big else -1
        nn[i] = n0


@njit(cache=True, nogil=True)
def nn2_mutual_4(a, bT, best, second, nn, back):  # pragma: no cover - compiled
    """:func:`nn2_mutual` for 256-bit descriptors (ORB) with ``b`` transposed, ``bT (4, N2)``: one
    query row's distances to all of ``b`` in a loop the compiler vectorizes, the backward nearest
    rows updated in the same loop, then the least distance, its first index and the least of the
    others (the second best, equal to the best on ties)."""
    na = a.shape[0]
    nb = bT.shape[1]
    big = np.int64(1) << 40
    back_d = np.full(nb, big, np.int64)
    dist = np.empty(nb, np.int64)
    for j in range(nb):
        back[j] = -1
    r0, r1, r2, r3 = bT[0], bT[1], bT[2], bT[3]
    for i in range(na):
        a0, a1, a2, a3 = a[i, 0], a[i, 1], a[i, 2], a[i, 3]
        m = big
        for j in range(nb):
            d = popcount64(a0 ^ r0[j]) + popcount64(a1 ^ r1[j]) + popcount64(a2 ^ r2[j]) + popcount64(a3 ^ r3[j])
            dist[j] = d
            upd = d < back_d[j]
            back_d[j] = d if upd else back_d[j]
            back[j] = i if upd else back[j]
            m = d if d < m else m
        n0 = 0
        while dist[n0] != m:
            n0 += 1
        s = big
        for j in range(n0):
            s = dist[j] if dist[j] < s else s
        for j in range(n0 + 1, nb):
            s = dist[j] if dist[j] < s else s
        best[i] = m
        second[i] = s if s < big else -1
        nn[i] = n0


def hamming_nn_mutual(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(best (N1,) float32, second (N1,) float32 (inf without a second), nn (N1,) int64,
    back (N2,) int64)`` of uint8 descriptors ``a (N1, D)``, ``b (N2, D)`` with ``D % 8 == 0``, both non-empty."""
    aw = np.ascontiguousarray(a, np.uint8).view(np.uint64)
    bw = np.ascontiguousarray(b, np.uint8).view(np.uint64)
    best = np.empty(len(aw), np.int64)
    second = np.empty(len(aw), np.int64)
    nn = np.empty(len(aw), np.int64)
    back = np.empty(len(bw), np.int64)
    if aw.shape[1] == 4:
        nn2_mutual_4(aw, np.ascontiguousarray(bw.T), best, second, nn, back)
    else:
        nn2_mutual(aw, bw, best, second, nn, back)
    sec = second.astype(np.float32)
    sec[second < 0] = np.inf
    return best.astype(np.float32), sec, nn, back


def warm() -> None:
    """Compile / load the kernels once on tiny inputs."""
    popcount64(np.uint64(3))
    hamming_nn_mutual(np.zeros((2, 8), np.uint8), np.ones((3, 8), np.uint8))
    hamming_nn_mutual(np.zeros((2, 32), np.uint8), np.ones((3, 32), np.uint8))
