"""Matching by projection, shared by tracking, local mapping, loop closing and localization:
which map points may be seen from a predicted pose, and guided matching of those to keypoints.

Projection with frustum, distance-range and viewing-angle tests follows ORB-SLAM's
``SearchLocalPoints`` / ``isInFrustum`` (Mur-Artal et al. 2015, sec. V-D); everything is one
vectorized NumPy pass over the local points.
"""
from __future__ import annotations

from typing import Callable

import numpy as np
from scipy.spatial import cKDTree

from vslam.geometry.camera import PinholeCamera
from vslam.map import matching_kernels
from vslam.map.mappoint import MapPointStore

USE_KERNELS = True  # the compiled kernels (identical results); False: the NumPy/SciPy reference


def project_local_points(
    points: MapPointStore,
    ids: np.ndarray,
    T_cam_world: np.ndarray,
    camera: PinholeCamera,
    margin: float = 0.0,
    max_view_angle_cos: float = 0.5,
    check_distance: bool = True,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Project map points ``ids`` into a camera at ``T_cam_world``.

    Returns:
        ``(ids_visible (M,), uv (M, 2) undistorted pixels, depth (M,))`` of the points in front of the
        camera, inside the image, within their scale-invariance distance range and seen at less than
        60 degrees from their mean viewing direction.
    """
    X = points.position[ids]
    R, t = T_cam_world[:3, :3], T_cam_world[:3, 3]
    Xc = X @ R.T + t
    if _compiled_projection(points, Xc):
        keep, u, v = matching_kernels.project_rest(
            Xc, X, ids, float(camera.fx), float(camera.fy), float(camera.cx), float(camera.cy),
            float(camera.width - 1 - margin), float(camera.height - 1 - margin), float(margin), -R.T @ t,
            points.min_distance, points.max_distance, points.normal, float(max_view_angle_cos), check_distance)
        return ids[keep], np.stack([u[keep], v[keep]], axis=1), Xc[keep, 2]
    z = Xc[:, 2]
    ok = z > 1e-3
    zs = np.where(ok, z, 1.0)
    u = camera.fx * Xc[:, 0] / zs + camera.cx
    v = camera.fy * Xc[:, 1] / zs + camera.cy
    ok &= (u >= margin) & (u <= camera.width - 1 - margin) & (v >= margin) & (v <= camera.height - 1 - margin)
    if check_distance:  # on the points inside the image only
        sel = np.flatnonzero(ok)
        ids_in = ids[sel]
        centre = -R.T @ t
        d = X[sel] - centre
        dist = np.linalg.norm(d, axis=1)
        good = (dist >= 0.8 * points.min_distance[ids_in]) & (dist <= 1.2 * points.max_distance[ids_in])
        cosang = np.einsum("ij,ij->i", d, points.normal[ids_in]) / np.maximum(dist, 1e-12)
        ok[sel] = good & (cosang >= max_view_angle_cos)
    return ids[ok], np.stack([u[ok], v[ok]], axis=1), z[ok]


def descriptor_distance(a: np.ndarray, b: np.ndarray, binary: bool) -> np.ndarray:
    """Distances between rows of broadcastable descriptor arrays ``a`` and ``b``: Hamming bits for
    binary (``uint8``) descriptors, L2 for float descriptors. Reduces the last axis."""
    if binary:
        if a.shape[-1] % 8 == 0 and a.shape == b.shape and a.ndim == 2:
            # 64-bit words: 4 popcounts per 256-bit ORB descriptor, summed column by column
            x = np.bitwise_xor(np.ascontiguousarray(a).view(np.uint64), np.ascontiguousarray(b).view(np.uint64))
            c = np.bitwise_count(x)
            out = c[:, 0].astype(np.float32)
            for j in range(1, c.shape[1]):
                out += c[:, j]
            return out
        x = np.bitwise_xor(a, b)
        if x.shape[-1] % 8 == 0:
            x = np.ascontiguousarray(x).view(np.uint64)
        return np.bitwise_count(x).sum(axis=-1).astype(np.float32)
    d = a.astype(np.float32) - b.astype(np.float32)
    return np.sqrt((d * d).sum(axis=-1))


def guided_match(
    proj_uv: np.ndarray,
    map_desc: np.ndarray,
    kp_uv: np.ndarray,
    kp_desc: np.ndarray,
    radius: float,
    binary: bool = True,
    max_distance: float | None = 64.0,
    ratio: float = 0.9,
    k: int = 8,
    kp_tree: cKDTree | Callable[[], cKDTree] | None = None,
    kp_free: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Match projected map points to keypoints within ``radius`` pixels by descriptor distance.

    The ``k`` nearest keypoints (in pixels) of each projection are candidates; the best descriptor
    distance must pass ``max_distance`` and the ratio test against the second best; a keypoint
    claimed by several map points keeps the closest one. ``kp_tree``: a ``cKDTree`` of ``kp_uv``, or a
    callable giving one (e.g. :meth:`vslam.map.keyframe.KeyFrame.keypoint_tree`), asked only when
    the tree is needed (the compiled grid search needs it for distance ties only); None: built here.

    Returns:
        ``(map_idx, kp_idx, distance)`` index arrays into ``proj_uv`` and ``kp_uv``.
    """
    empty = (np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros(0, np.float32))
    if len(proj_uv) == 0 or len(kp_uv) == 0:
        return empty
    k = min(k, len(kp_uv))
    if binary and USE_KERNELS and map_desc.dtype == np.uint8 and kp_desc.dtype == np.uint8:
        idx = _knn(proj_uv, kp_uv, radius, k, kp_tree)
        free = np.ones(len(kp_uv), bool) if kp_free is None else np.asarray(kp_free, bool)
        return matching_kernels.select_matches(
            idx, len(kp_uv), free, _words(map_desc), _words(kp_desc),
            np.float32(np.inf if max_distance is None else max_distance), max_distance is not None,
            np.float32(ratio), ratio < 1.0)
    tree = _tree(kp_tree, kp_uv)
    _, idx = tree.query(proj_uv, k=k, distance_upper_bound=radius)
    idx = idx.reshape(len(proj_uv), k)
    valid = idx < len(kp_uv)
    if kp_free is not None:
        valid &= kp_free[np.where(valid, idx, 0)]
    rows, cols = np.nonzero(valid)
    if len(rows) == 0:
        return empty
    # descriptor distances of the candidate pairs only, in a (projections, k) table (inf: none);
    # best and second best per map point without a sort (ties: the nearer keypoint, as kd order)
    D = np.full((len(proj_uv), k), np.inf, dtype=np.float32)
    D[rows, cols] = descriptor_distance(map_desc[rows], kp_desc[idx[rows, cols]], binary)
    j = np.argmin(D, axis=1)
    best = D[np.arange(len(proj_uv)), j]
    second = np.partition(D, 1, axis=1)[:, 1] if k > 1 else np.full(len(proj_uv), np.inf, np.float32)
    ok = np.isfinite(best)
    if max_distance is not None:
        ok &= best <= max_distance
    if ratio < 1.0:
        ok &= best < ratio * second
    m_idx = np.flatnonzero(ok)
    kp_idx = idx[m_idx, j[m_idx]]
    d = best[m_idx]
    # one map point per keypoint: keep the smallest distance
    o = _sort_pairs(kp_idx, d)
    m_idx, kp_idx, d = m_idx[o], kp_idx[o], d[o]
    first = np.ones(len(kp_idx), dtype=bool)
    first[1:] = kp_idx[1:] != kp_idx[:-1]
    return m_idx[first], kp_idx[first], d[first]


def _compiled_projection(points: MapPointStore, Xc: np.ndarray) -> bool:
    """Whether :func:`matching_kernels.project_rest` applies (float64 arrays, as the store keeps)."""
    return USE_KERNELS and all(a.dtype == np.float64 for a in (Xc, points.position, points.normal,
                                                               points.min_distance, points.max_distance))


def _tree(kp_tree: cKDTree | Callable[[], cKDTree] | None, kp_uv: np.ndarray) -> cKDTree:
    """The keypoint tree of :func:`guided_match`: given, given lazily (a callable), or built."""
    if kp_tree is None:
        return cKDTree(kp_uv)
    return kp_tree() if callable(kp_tree) else kp_tree


def _knn(proj_uv: np.ndarray, kp_uv: np.ndarray, radius: float, k: int,
         kp_tree: cKDTree | Callable[[], cKDTree] | None) -> np.ndarray:
    """``cKDTree(kp_uv).query(proj_uv, k, distance_upper_bound=radius)[1]`` as a ``(P, k)`` table, by
    the grid kernel; rows it cannot decide (distance ties) by the KD-tree."""
    proj = np.ascontiguousarray(proj_uv, dtype=np.float64)
    kp = np.ascontiguousarray(kp_uv, dtype=np.float64)
    idx, fallback, ok = matching_kernels.knn_grid(proj, kp, float(radius), k)
    rows = np.flatnonzero(fallback) if ok else np.arange(len(proj))
    if len(rows):
        tree = _tree(kp_tree, kp)
        idx[rows] = tree.query(proj[rows], k=k, distance_upper_bound=radius)[1].reshape(len(rows), k)
    return idx


def _words(desc: np.ndarray) -> np.ndarray:
    """Binary descriptors as ``uint64`` words (zero bytes appended: the Hamming distance is unchanged)."""
    d = np.ascontiguousarray(desc, dtype=np.uint8)
    if d.shape[1] % 8:
        d = np.pad(d, ((0, 0), (0, 8 - d.shape[1] % 8)))
    return d.view(np.uint64)


def _sort_pairs(group: np.ndarray, d: np.ndarray) -> np.ndarray:
    """The stable order of ``np.lexsort((d, group))``; for integer-valued ``d`` in ``[0, 2^20)``
    (Hamming distances) one stable argsort of the packed int64 key ``group * 2^20 + d``, faster."""
    if len(d) and float(d.max()) < 2**20 and float(d.min()) >= 0 and np.array_equal(d, np.round(d)):
        key = group.astype(np.int64) * (1 << 20) + d.astype(np.int64)
        return np.argsort(key, kind="stable")
    return np.lexsort((d, group))


def brute_force_match(
    desc1: np.ndarray, desc2: np.ndarray, binary: bool, ratio: float = 0.8, max_distance: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Nearest-neighbour matching with Lowe's ratio test and a mutual check
    (:func:`vslam.features.match.match_descriptors`, faiss)."""
    if len(desc1) < 2 or len(desc2) < 2:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    from vslam.features.match import match_descriptors

    i1, i2, _ = match_descriptors(desc1, desc2, binary=binary, ratio=ratio, mutual=True, max_distance=max_distance)
    return np.asarray(i1, dtype=np.int64), np.asarray(i2, dtype=np.int64)
