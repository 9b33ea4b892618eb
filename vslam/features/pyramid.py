"""Where keypoints are looked for: the scale pyramid (as OpenCV's ORB builds it), the per-level
feature quotas (ORB-SLAM's ``ORBextractor``) and the spread over a grid of cells."""
from __future__ import annotations

import cv2
import numpy as np

from vslam.errors import VslamError
from vslam.features import orb_kernels


def check_gray(gray: np.ndarray) -> np.ndarray:
    gray = np.asarray(gray)
    if gray.ndim == 3 and gray.shape[2] == 3:
        gray = cv2.cvtColor(gray, cv2.COLOR_BGR2GRAY)
    if gray.ndim != 2:
        raise VslamError(f"feature detection needs a (H, W) grayscale image, got shape {gray.shape}")
    if gray.dtype != np.uint8:
        raise VslamError(f"feature detection needs a uint8 image, got dtype {gray.dtype}")
    return np.ascontiguousarray(gray)


def build_pyramid(gray: np.ndarray, n_levels: int, scale_factor: float) -> list[np.ndarray]:
    """Image pyramid as OpenCV's ORB builds it: level ``l`` is ``round(W / s^l) x round(H / s^l)``,
    each resized (bilinear, ``INTER_LINEAR_EXACT``) from the previous level."""
    levels = [gray]
    h, w = gray.shape
    for lvl in range(1, n_levels):
        s = scale_factor**lvl
        size = (int(round(w / s)), int(round(h / s)))
        if min(size) < 8:
            break
        levels.append(cv2.resize(levels[-1], size, interpolation=cv2.INTER_LINEAR_EXACT))
    return levels


def level_quotas(n_features: int, n_levels: int, scale_factor: float) -> np.ndarray:
    """Features per level, a geometric series with ratio ``1/scale_factor`` summing to ``n_features``
    (ORB-SLAM's ``ORBextractor`` constructor)."""
    f = 1.0 / scale_factor
    per = n_features * (1 - f) / (1 - f**n_levels) * f ** np.arange(n_levels)
    q = np.floor(per).astype(np.int64)
    q[0] += n_features - q.sum()
    return q


def grid_select(uv: np.ndarray, score: np.ndarray, cell_size: float, n_keep: int) -> np.ndarray:
    """Indices of at most ``n_keep`` points spread over a grid of ``cell_size`` cells: the best
    point (highest ``score``) of every cell first, then the second best of every cell, and so on;
    inside a round, higher scores first (ties: lower index).

    Vectorized with two sorts of unique int64 keys (so an unstable quicksort is deterministic)."""
    n = len(uv)
    score = np.asarray(score)
    idx = np.arange(n, dtype=np.int64)
    small_int = n and np.all(score == np.round(score)) and score.min() >= 0 and score.max() < 2**16
    if small_int:  # FAST scores: the same order by counting sorts (compiled)
        cx = (uv[:, 0] // cell_size).astype(np.int64)
        cy = (uv[:, 1] // cell_size).astype(np.int64)
        if cx.min() >= 0 and cy.min() >= 0:
            return orb_kernels.grid_order(cx, cy, score.astype(np.int64), int(n_keep))
    # unique "badness" key, 0 for the best point: (score rank, index)
    if small_int:
        srank = (int(score.max()) - score).astype(np.int64) * n + idx  # FAST scores: small ints
    else:
        srank = np.empty(n, np.int64)
        srank[np.argsort(-score, kind="stable")] = idx
    if n <= n_keep:
        return np.argsort(srank)
    span = int(srank.max()) + 1
    cx = (uv[:, 0] // cell_size).astype(np.int64)
    cy = (uv[:, 1] // cell_size).astype(np.int64)
    cell = cy * (int(cx.max()) + 1) + cx
    order = np.argsort(cell * span + srank)  # by cell, then best first
    cs = cell[order]
    start = np.r_[True, cs[1:] != cs[:-1]]
    first = np.maximum.accumulate(np.where(start, idx, 0))
    rank = np.empty(n, np.int64)
    rank[order] = idx - first
    key = rank * span + srank  # unique: the n_keep smallest, in key order
    part = np.argpartition(key, n_keep - 1)[:n_keep] if n_keep > 0 else np.zeros(0, np.int64)
    return part[np.argsort(key[part])]
