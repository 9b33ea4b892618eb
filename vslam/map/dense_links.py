"""Dense links: a keyframe posed by dense RGB-D alignment to the previous keyframe, recorded by the
tracker (:mod:`vslam.frontend.depth_icp`) and used by local BA as extra constraints
(:mod:`vslam.backend.dense_links`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class DenseLink:
    """Keyframe ``kf_id`` was aligned densely to keyframe ``prev_kf_id``: ``T_prev_cur`` maps its
    camera points into the previous keyframe's camera; ``uv (N, 2)`` (undistorted pixels) and
    ``depth (N,)`` are sample points of its depth image."""

    kf_id: int
    prev_kf_id: int
    T_prev_cur: np.ndarray
    uv: np.ndarray
    depth: np.ndarray


def sample_depth_grid(depth: np.ndarray, K: np.ndarray, rows: int = 6, cols: int = 8,
                      min_depth: float = 0.1, max_depth: float = 6.0) -> tuple[np.ndarray, np.ndarray]:
    """``(uv (N, 2), depth (N,))`` at the centres of a ``rows x cols`` grid over the image, where the
    depth is valid and smooth (the 5x5 neighbourhood spans less than 2 % of the depth, so no
    object outline). Pixels are those of the depth image (registered to the undistorted colour)."""
    h, w = depth.shape[:2]
    v = ((np.arange(rows) + 0.5) * h / rows).astype(np.int64)
    u = ((np.arange(cols) + 0.5) * w / cols).astype(np.int64)
    vv, uu = np.meshgrid(v, u, indexing="ij")
    vv, uu = vv.ravel(), uu.ravel()
    offs = np.arange(-2, 3)
    nb = depth[np.clip(vv[:, None, None] + offs[None, :, None], 0, h - 1),
               np.clip(uu[:, None, None] + offs[None, None, :], 0, w - 1)].reshape(len(vv), -1).astype(float)
    nb = np.where(np.isfinite(nb), nb, 0.0)
    z = depth[vv, uu].astype(float)
    ok = np.isfinite(z) & (z >= min_depth) & (z <= max_depth) & np.all(nb > 0, axis=1)
    ok &= (nb.max(axis=1) - nb.min(axis=1)) < 0.02 * np.where(ok, z, 1.0)
    return np.column_stack([uu[ok], vv[ok]]).astype(float), z[ok]
