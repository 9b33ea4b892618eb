"""The frame record every dataset reader yields."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vslam.geometry.camera import PinholeCamera


@dataclass
class Frame:
    """One time step of a sequence.

    Attributes:
        index: position in the input sequence (0-based, in the dataset's own numbering,
            i.e. unaffected by ``--start-frame``).
        timestamp: seconds.
        image: the (left) image, ``uint8``, ``(H, W)`` grayscale or ``(H, W, 3)`` BGR.
        camera: intrinsics of ``image`` (distortion only if the image is not undistorted;
            ``baseline`` set for rectified stereo).
        image_right: the rectified right image of a stereo pair, or None.
        depth: float32 ``(H, W)`` depth in metres registered to ``image``; 0 where invalid; or None.
        T_world_cam: ground-truth 4x4 pose of the (left) camera when known, else None.
        path: the file the image came from (for messages).
    """

    index: int
    timestamp: float
    image: np.ndarray
    camera: PinholeCamera
    image_right: np.ndarray | None = None
    depth: np.ndarray | None = None
    T_world_cam: np.ndarray | None = None
    path: str | None = None

    @property
    def gray(self) -> np.ndarray:
        """The left image as ``uint8`` grayscale."""
        if self.image.ndim == 2:
            return self.image
        import cv2

        return cv2.cvtColor(self.image, cv2.COLOR_BGR2GRAY)
