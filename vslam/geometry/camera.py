"""Camera models: pinhole with radial-tangential (OpenCV "plumb bob") distortion, rectified stereo.

Conventions: pixels are ``(N, 2)`` float arrays ``(u, v)``; points are ``(N, 3)`` in the camera
frame (x right, y down, z forward). The right camera of a rectified stereo rig sits at
``+baseline`` metres along the left camera's x axis, so ``u_right = u_left - fx * baseline / z``.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class PinholeCamera:
    """Pinhole intrinsics, optional radtan distortion ``(k1, k2, p1, p2, k3)`` and stereo baseline.

    Example:
        >>> cam = PinholeCamera(500.0, 500.0, 320.0, 240.0, 640, 480)
        >>> cam.project(np.array([[0.0, 0.0, 2.0]]))
        array([[320., 240.]])
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    dist: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0)
    baseline: float | None = None  # metres, rectified stereo only

    @property
    def K(self) -> np.ndarray:
        """The 3x3 intrinsic matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def dist_coeffs(self) -> np.ndarray:
        """Distortion as OpenCV's ``(5,)`` array ``k1, k2, p1, p2, k3``."""
        d = np.zeros(5)
        d[: len(self.dist)] = self.dist
        return d

    @property
    def is_distorted(self) -> bool:
        return bool(np.any(np.asarray(self.dist) != 0.0))

    def project(self, X_cam: np.ndarray) -> np.ndarray:
        """Ideal (undistorted) projection u = fx x/z + cx, v = fy y/z + cy of ``(N, 3)`` points."""
        X_cam = np.asarray(X_cam, dtype=float)
        z = X_cam[:, 2]
        return np.stack([self.fx * X_cam[:, 0] / z + self.cx, self.fy * X_cam[:, 1] / z + self.cy], axis=1)

    def backproject(self, uv: np.ndarray, depth: np.ndarray) -> np.ndarray:
        """Inverse of :meth:`project` for undistorted pixels ``(N, 2)`` at depths ``z`` ``(N,)``."""
        uv = np.asarray(uv, dtype=float)
        z = np.asarray(depth, dtype=float)
        x = (uv[:, 0] - self.cx) / self.fx * z
        y = (uv[:, 1] - self.cy) / self.fy * z
        return np.stack([x, y, z], axis=1)

    def normalize(self, uv: np.ndarray) -> np.ndarray:
        """Undistorted pixels -> normalized image coordinates ``(x/z, y/z)``."""
        uv = np.asarray(uv, dtype=float)
        return np.stack([(uv[:, 0] - self.cx) / self.fx, (uv[:, 1] - self.cy) / self.fy], axis=1)

    def undistort_points(self, uv: np.ndarray) -> np.ndarray:
        """Distorted pixels -> ideal pinhole pixels (same K). A no-op for an undistorted camera."""
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        if not self.is_distorted or len(uv) == 0:
            return uv.copy()
        import cv2

        out = cv2.undistortPointsIter(
            uv.reshape(-1, 1, 2), self.K, self.dist_coeffs, None, self.K,
            (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 20, 1e-6),
        )
        return out.reshape(-1, 2)

    def distort_points(self, uv_ideal: np.ndarray) -> np.ndarray:
        """Ideal pinhole pixels -> distorted pixels (the radtan model applied in normalized coords)."""
        uv_ideal = np.asarray(uv_ideal, dtype=float).reshape(-1, 2)
        if not self.is_distorted:
            return uv_ideal.copy()
        k1, k2, p1, p2, k3 = self.dist_coeffs
        x, y = self.normalize(uv_ideal).T
        r2 = x * x + y * y
        radial = 1 + k1 * r2 + k2 * r2 * r2 + k3 * r2 ** 3
        xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        return np.stack([self.fx * xd + self.cx, self.fy * yd + self.cy], axis=1)

    def in_image(self, uv: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """Boolean mask of pixels inside the image (with an optional border margin)."""
        uv = np.asarray(uv, dtype=float)
        return (
            (uv[:, 0] >= margin) & (uv[:, 0] <= self.width - 1 - margin)
            & (uv[:, 1] >= margin) & (uv[:, 1] <= self.height - 1 - margin)
        )

    def scaled(self, factor: float) -> "PinholeCamera":
        """The same camera for images resized by ``factor``."""
        return PinholeCamera(
            self.fx * factor, self.fy * factor, (self.cx + 0.5) * factor - 0.5, (self.cy + 0.5) * factor - 0.5,
            int(round(self.width * factor)), int(round(self.height * factor)), self.dist, self.baseline,
        )

    def to_dict(self) -> dict:
        return {
            "fx": self.fx, "fy": self.fy, "cx": self.cx, "cy": self.cy,
            "width": self.width, "height": self.height,
            "dist": list(map(float, self.dist)), "baseline": self.baseline,
        }


RGBD_VIRTUAL_BASELINE = 0.08  # metres; ORB-SLAM2's TUM settings use bf = 40 for fx ~ 517


def stereo_bf(camera: PinholeCamera, sensor: str) -> float:
    """``bf = fx * baseline`` of the stereo residual ``u_right = u - bf / z`` (ORB-SLAM2): the real
    baseline for rectified stereo, the virtual :data:`RGBD_VIRTUAL_BASELINE` for RGB-D (depth becomes
    a virtual right-image coordinate), 0 for monocular (no third coordinate)."""
    if sensor == "stereo":
        return camera.fx * float(camera.baseline or 0.0)
    if sensor == "rgbd":
        return camera.fx * RGBD_VIRTUAL_BASELINE
    return 0.0
