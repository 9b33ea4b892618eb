"""Compiled (numba) kernels of :func:`vslam.map.matching.guided_match` and
:func:`vslam.map.matching.project_local_points`.

They return exactly what the NumPy/SciPy code they replace returned:

- :func:`knn_grid` finds the ``k`` nearest keypoints of each projection strictly within the
  radius (``cKDTree.query(..., distance_upper_bound=radius)``) with a uniform grid instead of the
  KD-tree; squared distances are ``dx * dx + dy * dy`` in float64 as SciPy computes them, sorted
  ascending. Where two candidates that decide the result lie at exactly the same distance the
  KD-tree's order is its traversal order, which a grid cannot reproduce: those rows are flagged and
  the caller asks the KD-tree for them.
- :func:`select_matches` is the descriptor part: Hamming distances (float32, integer valued) of the
  candidate pairs, the best (first minimum in candidate order, as ``np.argmin``) and second best
  (``np.partition``) per projection, the ``max_distance`` and float32 ratio tests, then one map point
  per keypoint (smallest distance, ties: lower map index), ordered by keypoint.
- :func:`project_rest` is the elementwise part of the projection after the NumPy matrix product.

numba does not contract ``a * b + c`` into fused multiply-adds unless ``fastmath`` is on, which
these kernels never set; ``error_model="numpy"``: a division by zero gives inf/NaN as in NumPy.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from vslam.features.match_kernels import popcount64


@njit(cache=True, nogil=True, error_model="numpy")
def _grid(kp, umin, vmin, cs, nx, ny):  # pragma: no cover - compiled
    """Counting sort of the keypoints into ``nx * ny`` cells of ``cs`` pixels: ``(start (cells + 1),
    order, u, v)`` with cell ``c``'s keypoints at ``start[c]:start[c + 1]`` (ascending index)."""
    n = kp.shape[0]
    cell = np.empty(n, np.int64)
    start = np.zeros(nx * ny + 1, np.int64)
    for i in range(n):
        c = int(np.floor((kp[i, 1] - vmin) / cs)) * nx + int(np.floor((kp[i, 0] - umin) / cs))
        cell[i] = c
        start[c + 1] += 1
    for c in range(nx * ny):
        start[c + 1] += start[c]
    fill = start[:-1].copy()
    order = np.empty(n, np.int64)  # keypoints in cell order, with their coordinates beside them
    su = np.empty(n)
    sv = np.empty(n)
    for i in range(n):
        s = fill[cell[i]]
        order[s] = i
        su[s] = kp[i, 0]
        sv[s] = kp[i, 1]
        fill[cell[i]] += 1
    return start, order, su, sv


@njit(cache=True, nogil=True, error_model="numpy")
def knn_grid(proj, kp, radius, k):  # pragma: no cover - compiled
    """``(idx (P, k) int64, fallback (P,) bool, ok)``: the ``k`` nearest keypoints ``kp (N, 2)`` of
    each ``proj (P, 2)`` with squared distance ``< radius**2`` (missing: ``N``), nearest first;
    ``fallback`` marks rows with a distance tie among the first ``k + 1`` or a non-finite query;
    ``ok`` is False (nothing computed) when the grid would be too large or a keypoint is not finite."""
    n = kp.shape[0]
    p_all = proj.shape[0]
    idx = np.full((p_all, k), n, np.int64)
    fallback = np.zeros(p_all, np.bool_)
    umin, vmin, umax, vmax = kp[0, 0], kp[0, 1], kp[0, 0], kp[0, 1]
    for i in range(n):
        if not (np.isfinite(kp[i, 0]) and np.isfinite(kp[i, 1])):
            return idx, fallback, False  # the KD-tree answers for all rows
        umin = min(umin, kp[i, 0])
        umax = max(umax, kp[i, 0])
        vmin = min(vmin, kp[i, 1])
        vmax = max(vmax, kp[i, 1])
    cs = radius
    if not (cs > 0.0 and np.isfinite(cs) and np.isfinite(umax - umin) and np.isfinite(vmax - vmin)):
        return idx, fallback, False
    fx = (umax - umin) / cs
    fy = (vmax - vmin) / cs
    if fx > 4096.0 or fy > 4096.0 or (fx + 1.0) * (fy + 1.0) > 4.0 * n + 65536.0:
        return idx, fallback, False
    nx = int(fx) + 1
    ny = int(fy) + 1
    start, order, su, sv = _grid(kp, umin, vmin, cs, nx, ny)
    r2 = radius * radius
    bd = np.empty(k + 1)
    bi = np.empty(k + 1, np.int64)
    for p in range(p_all):
        qu = proj[p, 0]
        qv = proj[p, 1]
        if not (np.isfinite(qu) and np.isfinite(qv)):
            fallback[p] = True
            continue
        x0 = max(int(np.floor(max((qu - radius - umin) / cs, -1.0))), 0)
        x1 = min(int(np.floor(min((qu + radius - umin) / cs, nx + 1.0))), nx - 1)
        y0 = max(int(np.floor(max((qv - radius - vmin) / cs, -1.0))), 0)
        y1 = min(int(np.floor(min((qv + radius - vmin) / cs, ny + 1.0))), ny - 1)
        cnt = 0
        for cy in range(y0, y1 + 1):
            for cx in range(x0, x1 + 1):
                c = cy * nx + cx
                for s in range(start[c], start[c + 1]):
                    du = su[s] - qu
                    dv = sv[s] - qv
                    d2 = du * du + dv * dv
                    if d2 < r2 and (cnt <= k or d2 < bd[k]):
                        # insertion into the sorted top k + 1 (when full, the last one drops out)
                        j = cnt if cnt <= k else k
                        cnt = min(cnt + 1, k + 1)
                        while j > 0 and bd[j - 1] > d2:
                            bd[j] = bd[j - 1]
                            bi[j] = bi[j - 1]
                            j -= 1
                        bd[j] = d2
                        bi[j] = order[s]
        for j in range(1, cnt):
            if bd[j] == bd[j - 1]:
                fallback[p] = True
        for j in range(min(cnt, k)):
            idx[p, j] = bi[j]
    return idx, fallback, True


@njit(cache=True, nogil=True, error_model="numpy")
def select_matches(idx, n, free, map_desc, kp_desc, max_distance, use_max, ratio, use_ratio):  # pragma: no cover
    """``(m_idx, kp_idx, distance float32)`` of :func:`vslam.map.matching.guided_match` from the
    candidate table ``idx (P, k)`` (``n``: none), keypoint mask ``free (N,)`` and ``uint64``-word
    descriptors; ``max_distance`` and ``ratio`` are float32 like NumPy's weak-scalar arithmetic."""
    p_all, k = idx.shape
    words = map_desc.shape[1]
    inf = np.float32(np.inf)
    best_d = np.full(n, inf, np.float32)
    best_m = np.full(n, -1, np.int64)
    n_kept = 0
    for p in range(p_all):
        best = inf
        second = inf
        jbest = -1
        for col in range(k):
            i = idx[p, col]
            v = inf
            if i < n and free[i]:
                cntb = np.int64(0)
                for w in range(words):
                    cntb += popcount64(map_desc[p, w] ^ kp_desc[i, w])
                v = np.float32(cntb)
            if v < best:
                second = best
                best = v
                jbest = col
            elif v < second:
                second = v
        if jbest < 0 or not np.isfinite(best):
            continue
        if use_max and not (best <= max_distance):
            continue
        if use_ratio and not (best < ratio * second):
            continue
        i = idx[p, jbest]
        if best_m[i] < 0:
            n_kept += 1
            best_m[i] = p
            best_d[i] = best
        elif best < best_d[i]:
            best_m[i] = p
            best_d[i] = best
    m_out = np.empty(n_kept, np.int64)
    k_out = np.empty(n_kept, np.int64)
    d_out = np.empty(n_kept, np.float32)
    o = 0
    for i in range(n):
        if best_m[i] >= 0:
            m_out[o] = best_m[i]
            k_out[o] = i
            d_out[o] = best_d[i]
            o += 1
    return m_out, k_out, d_out


@njit(cache=True, nogil=True, error_model="numpy")
def project_rest(Xc, X, ids, fx, fy, cx, cy, umax, vmax, margin, centre, min_distance, max_distance, normal,
                 max_view_angle_cos, check_distance):  # pragma: no cover - compiled
    """``(keep (M,) bool, u (M,), v (M,))`` of :func:`vslam.map.matching.project_local_points` from
    the camera points ``Xc = X @ R.T + t`` (NumPy's product) and the gathered world points ``X``."""
    m_all = Xc.shape[0]
    keep = np.zeros(m_all, np.bool_)
    u = np.empty(m_all)
    v = np.empty(m_all)
    for i in range(m_all):
        z = Xc[i, 2]
        ok = z > 1e-3
        zs = z if ok else 1.0
        ui = fx * Xc[i, 0] / zs + cx
        vi = fy * Xc[i, 1] / zs + cy
        u[i] = ui
        v[i] = vi
        ok = ok and (ui >= margin) and (ui <= umax) and (vi >= margin) and (vi <= vmax)
        if ok and check_distance:
            pid = ids[i]
            d0 = X[i, 0] - centre[0]
            d1 = X[i, 1] - centre[1]
            d2 = X[i, 2] - centre[2]
            dist = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
            good = (dist >= 0.8 * min_distance[pid]) and (dist <= 1.2 * max_distance[pid])
            dot = d0 * normal[pid, 0] + d1 * normal[pid, 1] + d2 * normal[pid, 2]
            ok = good and (dot / max(dist, 1e-12) >= max_view_angle_cos)
        keep[i] = ok
    return keep, u, v


def warm() -> None:
    """Call each kernel once on tiny inputs (loads the cached machine code)."""
    kp = np.array([[0.0, 0.0], [3.0, 1.0]])
    idx, _, _ = knn_grid(np.array([[0.5, 0.5]]), kp, 4.0, 2)
    desc = np.zeros((2, 4), np.uint64)
    select_matches(idx, 2, np.ones(2, np.bool_), desc[:1], desc, np.float32(64.0), True, np.float32(0.9), True)
    ids = np.array([0], np.int64)
    X = np.array([[0.0, 0.0, 2.0]])
    project_rest(X, X, ids, 1.0, 1.0, 1.0, 1.0, 3.0, 3.0, 0.0, np.zeros(3), np.ones(1), np.ones(1) * 9.0,
                 np.array([[0.0, 0.0, 1.0]]), 0.5, True)
