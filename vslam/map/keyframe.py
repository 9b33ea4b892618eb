"""Keyframes: the frames kept in the map (pose, keypoints, descriptors, depth; never the image)."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from scipy.spatial import cKDTree


@dataclass
class KeyFrame:
    """One keyframe.

    Attributes:
        id: keyframe id (0, 1, ... in insertion order).
        frame_index, timestamp: the input frame it was made from.
        T_world_cam: ``(4, 4)`` pose (updated by the backend).
        uv: ``(N, 2)`` detected (distorted) pixels; uv_undist: the same, undistorted.
        descriptors: ``(N, D)`` or None (KLT tracking without descriptors).
        octave: ``(N,)`` pyramid level of each keypoint.
        depth: ``(N,)`` metric depth from RGB-D/stereo, NaN where unknown.
        point_ids: ``(N,)`` the map point each keypoint observes, ``-1`` for none.
        segment: the map segment (a new one starts after tracking is lost and re-initialized).
    """

    id: int
    frame_index: int
    timestamp: float
    T_world_cam: np.ndarray
    uv: np.ndarray
    uv_undist: np.ndarray
    descriptors: np.ndarray | None
    octave: np.ndarray
    depth: np.ndarray
    point_ids: np.ndarray
    segment: int = 0
    u_right: np.ndarray | None = None
    bad: bool = False
    extra: dict = field(default_factory=dict)

    @property
    def T_cam_world(self) -> np.ndarray:
        T = np.eye(4)
        R = self.T_world_cam[:3, :3]
        T[:3, :3] = R.T
        T[:3, 3] = -R.T @ self.T_world_cam[:3, 3]
        return T

    @property
    def centre(self) -> np.ndarray:
        return self.T_world_cam[:3, 3].copy()

    def observed_ids(self) -> np.ndarray:
        return self.point_ids[self.point_ids >= 0]

    def keypoint_tree(self) -> "cKDTree":
        """A kd-tree (``scipy.spatial.cKDTree``) of ``uv_undist`` for guided matching into this
        keyframe, built on first use and kept (not a field: never saved with the map)."""
        tree = self.__dict__.get("_keypoint_tree")
        if tree is None or tree.n != len(self.uv_undist):
            from scipy.spatial import cKDTree

            tree = cKDTree(self.uv_undist)
            self.__dict__["_keypoint_tree"] = tree
        return tree
