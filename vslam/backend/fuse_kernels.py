"""Compiled (numba) kernels of :meth:`vslam.backend.fuse.NeighbourFusion._fuse_into`, the part around
projection and guided matching that was ~25 small NumPy expressions per neighbour keyframe.

They give exactly what the NumPy code they replace gave (:func:`candidate_points`: the alive
points of ``pts`` the keyframe does not observe yet, in order; :func:`fuse_matches`: the chi-square
test, the new observations written into ``point_ids`` / ``n_obs`` and the ``(loser, winner)``
pairs of :meth:`vslam.map.map.Map.merge_points`). The chi-square arithmetic keeps NumPy's
operations and their order (``du * du + dv * dv`` then ``/ sigma2``, plus ``(disp - bf / z) ** 2 /
sigma2`` where a disparity exists); ``sigma2`` (a power) stays in NumPy. numba does not contract
``a * b + c`` into fused multiply-adds without ``fastmath``, which these kernels never set.
"""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def candidate_points(pts, alive, point_ids, n_points):  # pragma: no cover - compiled
    """``pts[alive[pts]]`` less the points in ``point_ids`` (``-1``: none), order kept; ``n_points``
    is the store's size (ids ``0 .. n_points - 1``)."""
    observed = np.zeros(n_points + 1, np.bool_)
    for i in range(point_ids.shape[0]):
        if point_ids[i] >= 0:
            observed[point_ids[i]] = True
    out = np.empty(pts.shape[0], np.int64)
    n = 0
    for i in range(pts.shape[0]):
        p = pts[i]
        if alive[p] and not observed[p]:
            out[n] = p
            n += 1
    return out[:n]


@njit(cache=True, nogil=True, error_model="numpy")
def fuse_matches(p, kp, zp, proj_uv_m, kp_uv, sigma2, u0, u_right, bf, use_disp, chi2_mono, chi2_stereo,
                 point_ids, alive, n_obs, remap):  # pragma: no cover - compiled
    """The matches ``p`` (map point) <-> ``kp`` (keypoint) at depth ``zp`` and projection
    ``proj_uv_m`` that pass the chi-square test: a free keypoint (no point, or a dead one) takes
    the point (``point_ids``, ``n_obs`` updated in place); a keypoint with another live point gives
    a ``(loser, winner)`` pair through ``remap`` (the one with fewer observations, counted after
    this call's new observations, loses; ties: the keypoint's point). ``use_disp``: test the
    disparity ``u0[kp] - u_right[kp]`` (finite ones) against ``bf / zp`` too; ``sigma2`` is per match,
    ``kp_uv``, ``u0``, ``u_right`` per keypoint. Returns ``(loser, winner)``."""
    m_all = p.shape[0]
    ok = np.zeros(m_all, np.bool_)
    for i in range(m_all):
        du = proj_uv_m[i, 0] - kp_uv[kp[i], 0]
        dv = proj_uv_m[i, 1] - kp_uv[kp[i], 1]
        chi2 = (du * du + dv * dv) / sigma2[i]
        thr = chi2_mono
        if use_disp:
            disp = u0[kp[i]] - u_right[kp[i]]
            if np.isfinite(disp):
                e = disp - bf / zp[i]
                chi2 = chi2 + (e * e) / sigma2[i]
                thr = chi2_stereo
            else:
                chi2 = chi2 + 0.0 / sigma2[i]
        ok[i] = chi2 <= thr
    cur = np.empty(m_all, np.int64)
    dup = np.zeros(m_all, np.bool_)
    for i in range(m_all):  # every keypoint's point before this call's writes (kp is unique)
        cur[i] = point_ids[kp[i]]
    for i in range(m_all):
        if not ok[i]:
            continue
        c = cur[i]
        if c < 0 or not alive[c if c >= 0 else 0]:
            point_ids[kp[i]] = p[i]
            n_obs[p[i]] += 1
        elif c != p[i]:
            dup[i] = True
    n_dup = 0
    for i in range(m_all):
        if dup[i]:
            n_dup += 1
    loser = np.empty(n_dup, np.int64)
    winner = np.empty(n_dup, np.int64)
    j = 0
    for i in range(m_all):
        if dup[i]:
            a = remap[p[i]]
            b = remap[cur[i]]
            if n_obs[a] >= n_obs[b]:
                loser[j] = b
                winner[j] = a
            else:
                loser[j] = a
                winner[j] = b
            j += 1
    return loser, winner


def warm() -> None:
    """Call each kernel once on tiny inputs (loads the cached machine code)."""
    ids = np.array([0, 1], np.int64)
    alive = np.ones(2, np.bool_)
    point_ids = np.array([-1, 1], np.int64)
    candidate_points(ids, alive, point_ids, 2)
    uv = np.zeros((2, 2))
    one = np.ones(2)
    fuse_matches(ids, ids, one, uv, uv, one, one, one, 1.0, True, 5.991, 7.815, point_ids, alive,
                 np.zeros(2, np.int64), np.array([0, 1, -1], np.int64))
