"""The :class:`Features` type: keypoints and descriptors of one image, as every detector returns them."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class Features:
    """Keypoints and descriptors of one image.

    Attributes:
        uv: ``(N, 2) float32`` pixel coordinates at level 0, as detected (in the possibly
            distorted image).
        descriptors: ``(N, D)``; ``uint8`` packed bits for binary descriptors, ``float32`` otherwise.
        octave: ``(N,) int32`` pyramid level (0 = full resolution).
        response: ``(N,) float32`` detector score.
        angle: ``(N,) float32`` orientation in degrees ``[0, 360)`` (or -1 when not defined).
        size: ``(N,) float32`` keypoint diameter in level-0 pixels.
        binary: True for Hamming descriptors, False for L2.
        scale_factor: pyramid scale between levels; level ``l`` has scale ``scale_factor**l``,
            so the measurement sigma of a keypoint is ``scale_factor**octave`` pixels.
    """

    uv: np.ndarray
    descriptors: np.ndarray
    octave: np.ndarray
    response: np.ndarray
    angle: np.ndarray
    size: np.ndarray
    binary: bool
    scale_factor: float = 1.2

    def __len__(self) -> int:
        return int(self.uv.shape[0])

    @property
    def scales(self) -> np.ndarray:
        """``(N,)`` scale of each keypoint's level, ``scale_factor ** octave``."""
        return np.power(float(self.scale_factor), self.octave.astype(np.float64))

    def subset(self, idx: np.ndarray) -> "Features":
        """The features at ``idx`` (indices or boolean mask), same metadata."""
        return Features(
            self.uv[idx], self.descriptors[idx], self.octave[idx], self.response[idx],
            self.angle[idx], self.size[idx], self.binary, self.scale_factor,
        )

    @staticmethod
    def empty(binary: bool = True, dim: int = 32, scale_factor: float = 1.2) -> "Features":
        dt = np.uint8 if binary else np.float32
        z = np.zeros(0, np.float32)
        return Features(np.zeros((0, 2), np.float32), np.zeros((0, dim), dt), np.zeros(0, np.int32),
                        z, z.copy(), z.copy(), binary, scale_factor)
