"""Remapping images of a fisheye camera or a raw stereo rig to an ideal (rectified) pinhole
camera, so that every later stage sees a pinhole camera (:mod:`vslam.datasets.calibration` reads
the calibration)."""
from __future__ import annotations

import logging
from typing import TYPE_CHECKING

import numpy as np

from vslam.errors import CalibrationError
from vslam.geometry.camera import PinholeCamera

if TYPE_CHECKING:
    from vslam.datasets.calibration import Calibration

log = logging.getLogger(__name__)


# -- remapping to an ideal pinhole camera ------------------------------------------------------
class Rectifier:
    """Remap images of a fisheye camera or a raw stereo rig to an ideal (rectified) pinhole camera.

    Fisheye: ``cv2.fisheye.initUndistortRectifyMap`` with the new K from
    ``cv2.fisheye.estimateNewCameraMatrixForUndistortRectify`` (``balance``: 0 keeps only valid
    pixels, 1 keeps the whole field of view). Stereo: Bouguet rectification
    (``cv2.stereoRectify`` / ``cv2.fisheye.stereoRectify``), the output camera has the baseline.
    ``R_rect_cam`` rotates the original left camera into the rectified one.
    """

    def __init__(self, cal: Calibration, balance: float = 0.0) -> None:
        import cv2

        self.calibration = cal
        c0 = cal.camera
        size = (c0.width, c0.height)
        D0 = np.asarray(c0.dist[:4], float) if cal.model == "equidistant" else c0.dist_coeffs
        self.maps_right = None
        if cal.right is None:
            R1 = np.eye(3)
            if cal.model == "equidistant":
                P1 = cv2.fisheye.estimateNewCameraMatrixForUndistortRectify(c0.K, D0, size, R1, balance=balance)
                self.maps_left = cv2.fisheye.initUndistortRectifyMap(c0.K, D0, R1, P1, size, cv2.CV_16SC2)
            else:
                P1, _ = cv2.getOptimalNewCameraMatrix(c0.K, D0, size, balance)
                self.maps_left = cv2.initUndistortRectifyMap(c0.K, D0, R1, P1, size, cv2.CV_16SC2)
            baseline = None
        else:
            c1 = cal.right
            if (c1.width, c1.height) != size:
                raise CalibrationError(f"{cal.source}: the two cameras of the rig have different image sizes")
            T = cal.T_right_left
            if cal.model == "equidistant":
                D1 = np.asarray(c1.dist[:4], float)
                R1, R2, P1, P2, _Q = cv2.fisheye.stereoRectify(
                    c0.K, D0, c1.K, D1, size, T[:3, :3], T[:3, 3], cv2.CALIB_ZERO_DISPARITY, size, balance, 1.0)
                self.maps_left = cv2.fisheye.initUndistortRectifyMap(c0.K, D0, R1, P1, size, cv2.CV_16SC2)
                self.maps_right = cv2.fisheye.initUndistortRectifyMap(c1.K, D1, R2, P2, size, cv2.CV_16SC2)
            else:
                D1 = c1.dist_coeffs
                R1, R2, P1, P2, *_ = cv2.stereoRectify(
                    c0.K, D0, c1.K, D1, size, T[:3, :3], T[:3, 3], flags=cv2.CALIB_ZERO_DISPARITY, alpha=balance)
                self.maps_left = cv2.initUndistortRectifyMap(c0.K, D0, R1, P1, size, cv2.CV_16SC2)
                self.maps_right = cv2.initUndistortRectifyMap(c1.K, D1, R2, P2, size, cv2.CV_16SC2)
            baseline = float(-P2[0, 3] / P2[0, 0])
            if not baseline > 0:
                raise CalibrationError(f"{cal.source}: rectification gave baseline {baseline}; check the extrinsics")
        self.R_rect_cam = np.asarray(R1, float)
        self.camera = PinholeCamera(float(P1[0, 0]), float(P1[1, 1]), float(P1[0, 2]), float(P1[1, 2]),
                                    c0.width, c0.height, baseline=baseline)

    def left(self, image: np.ndarray, nearest: bool = False) -> np.ndarray:
        """Remap a left (or only) image; ``nearest`` for depth maps."""
        import cv2

        interp = cv2.INTER_NEAREST if nearest else cv2.INTER_LINEAR
        return cv2.remap(image, *self.maps_left, interp)

    def right(self, image: np.ndarray) -> np.ndarray:
        import cv2

        if self.maps_right is None:
            raise CalibrationError("this calibration has no right camera")
        return cv2.remap(image, *self.maps_right, cv2.INTER_LINEAR)


def frame_camera(cal: Calibration) -> tuple[PinholeCamera, Rectifier | None]:
    """The camera the pipeline sees and the :class:`Rectifier` to apply to images (None: none)."""
    if not cal.needs_remap:
        return cal.camera, None
    rect = Rectifier(cal, balance=float(cal.extras.get("balance", 0.0)))
    c = rect.camera
    log.info("%s: images are remapped to a pinhole camera (fx %.1f, field of view %.0f x %.0f deg)", cal.source,
             c.fx, 2 * np.degrees(np.arctan(c.width / (2 * c.fx))), 2 * np.degrees(np.arctan(c.height / (2 * c.fy))))
    return rect.camera, rect
