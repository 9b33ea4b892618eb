"""OpenCV's ORB descriptors of given keypoints, the reference the compiled ones must equal."""
from __future__ import annotations

import cv2
import numpy as np


def opencv_orb(img: np.ndarray, x: np.ndarray, y: np.ndarray, angle: np.ndarray, patch_size: int = 31,
               border: int = 19) -> tuple[np.ndarray, np.ndarray]:
    """``cv2.ORB_create(nlevels=1, edgeThreshold=border, patchSize=patch_size).compute`` on
    ``cv2.KeyPoint`` s at ``(x, y)`` with ``angle`` (degrees): the input indices of the keypoints it
    kept (carried through as ``class_id``) and their ``(K, 32) uint8`` descriptors."""
    kps = [cv2.KeyPoint(float(u), float(v), float(patch_size), float(a), 0.0, 0, i)
           for i, (u, v, a) in enumerate(zip(np.asarray(x).tolist(), np.asarray(y).tolist(),
                                             np.asarray(angle, np.float32).tolist()))]
    orb = cv2.ORB_create(nfeatures=max(1, len(kps)), nlevels=1, edgeThreshold=border, patchSize=patch_size)
    out, desc = orb.compute(img, kps)
    if desc is None or not out:
        return np.zeros(0, np.int64), np.zeros((0, 32), np.uint8)
    return np.array([k.class_id for k in out], np.int64), desc
