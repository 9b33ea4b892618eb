"""Sparse map export: the map points (triangulated landmarks) as a coloured PLY point cloud."""
from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from vslam.errors import VslamError
from vslam.reconstruction.ply import write_point_cloud

log = logging.getLogger(__name__)


def export_sparse(
    path: str | Path, X_world: np.ndarray, colors: np.ndarray | None = None, binary: bool = True
) -> Path:
    """Write map points ``X_world (N, 3)`` (world frame, metres) with optional ``colors (N, 3)``
    uint8 RGB to a PLY point cloud; non-finite points are dropped. Returns the path.

    Example:
        >>> export_sparse("out/sparse.ply", np.zeros((1, 3)), np.array([[255, 0, 0]], np.uint8))  # doctest: +SKIP
    """
    X_world = np.asarray(X_world, dtype=np.float64).reshape(-1, 3) if np.size(X_world) else np.zeros((0, 3))
    if colors is not None:
        colors = np.asarray(colors)
        if colors.shape != X_world.shape:
            raise VslamError(f"export_sparse: colors {colors.shape} must match points {X_world.shape}")
    keep = np.all(np.isfinite(X_world), axis=1)
    if not keep.all():
        log.warning("export_sparse: dropping %d non-finite points of %d", int((~keep).sum()), len(X_world))
        X_world = X_world[keep]
        colors = colors[keep] if colors is not None else None
    return write_point_cloud(path, X_world.astype(np.float32), colors=colors, binary=binary)


__all__ = ["export_sparse"]
