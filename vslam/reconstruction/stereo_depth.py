"""Dense depth from a rectified stereo pair with OpenCV's semi-global block matching (SGBM).

Disparity by Hirschmüller's semi-global matching ("Stereo Processing by Semiglobal Matching and
Mutual Information", PAMI 2008; ``cv2.StereoSGBM``, 3-way variant), then depth by the rectified
stereo relation ``z = fx * B / d`` (Hartley & Zisserman, "Multiple View Geometry", 2nd ed., sec.
11.12 / eq. for parallel cameras). Outliers are removed by SGBM's uniqueness test (best cost at
least ``uniqueness_ratio`` % below the second best), its left-right consistency check
(``disp12_max_diff``), speckle filtering (connected regions smaller than ``speckle_window`` pixels
whose disparity varies by at most ``speckle_range`` are dropped), and a depth range: the depth
error grows as ``sigma_z = z^2 sigma_d / (fx B)``, so far points are cut at ``max_depth``
(by default where the disparity falls below ``min_disparity_px`` pixels).

Example:
    >>> cam = PinholeCamera(525.0, 525.0, 319.5, 239.5, 640, 480, baseline=0.1)
    >>> depth = depth_from_stereo(left_gray, right_gray, cam)     # doctest: +SKIP
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from vslam.errors import CalibrationError, VslamError
from vslam.geometry.camera import PinholeCamera


@dataclass(frozen=True)
class StereoDepthConfig:
    """SGBM and filtering settings.

    Attributes:
        num_disparities: disparity search range in pixels (a multiple of 16); the nearest depth
            seen is ``fx B / num_disparities`` (128: 0.41 m for the synthetic rig, 3 m on KITTI).
            SGBM leaves the leftmost ``num_disparities`` columns without depth, so None picks
            128 capped at a fifth of the image width (64 at 320 px).
        block_size: matching window (odd, 3..11).
        uniqueness_ratio: percent margin of the best match over the second best.
        speckle_window, speckle_range: speckle filter (region size in pixels, disparity variation).
        disp12_max_diff: left-right consistency tolerance in pixels (< 0 disables it).
        max_depth: metres; None = ``fx B / min_disparity_px``.
        min_disparity_px: used for the default ``max_depth``.
        border: pixels at the image border set invalid (SGBM is unreliable there).
    """

    num_disparities: int | None = None
    block_size: int = 5
    uniqueness_ratio: int = 10
    speckle_window: int = 100
    speckle_range: int = 2
    disp12_max_diff: int = 1
    max_depth: float | None = None
    min_disparity_px: float = 8.0
    border: int = 4

    def __post_init__(self) -> None:
        if self.num_disparities is not None and (self.num_disparities < 16 or self.num_disparities % 16):
            raise VslamError(f"stereo num_disparities must be a positive multiple of 16, got {self.num_disparities}")
        if self.block_size < 1 or self.block_size % 2 == 0:
            raise VslamError(f"stereo block_size must be odd and positive, got {self.block_size}")


def default_max_depth(camera: PinholeCamera, min_disparity_px: float = 8.0) -> float:
    """``fx B / d_min``: the depth at which the disparity drops to ``min_disparity_px`` pixels."""
    return float(camera.fx * _baseline(camera) / min_disparity_px)


def _baseline(camera: PinholeCamera) -> float:
    if camera.baseline is None or not camera.baseline > 0:
        raise CalibrationError(
            f"stereo depth needs a rectified stereo camera with a positive baseline, got baseline={camera.baseline}; "
            "open the sequence with sensor='stereo'"
        )
    return float(camera.baseline)


def auto_num_disparities(width: int) -> int:
    """128, or less for narrow images: a multiple of 16 no larger than ``width / 5`` (at least 16)."""
    return int(max(16, min(128, (width // 5) // 16 * 16)))


def _gray(image: np.ndarray, what: str) -> np.ndarray:
    image = np.asarray(image)
    if image.ndim == 3:
        image = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    if image.ndim != 2 or image.dtype != np.uint8:
        raise VslamError(f"stereo {what} image must be uint8 gray or BGR, got {image.dtype} {image.shape}")
    return image


def disparity_sgbm(left_gray: np.ndarray, right_gray: np.ndarray, config: StereoDepthConfig = StereoDepthConfig()) -> np.ndarray:
    """SGBM disparity ``float32 (H, W)`` in pixels of the left image; ``<= 0`` where invalid."""
    left, right = _gray(left_gray, "left"), _gray(right_gray, "right")
    if left.shape != right.shape:
        raise VslamError(f"stereo images differ in size: left {left.shape}, right {right.shape}")
    bs = config.block_size
    nd = config.num_disparities if config.num_disparities is not None else auto_num_disparities(left.shape[1])
    sgbm = cv2.StereoSGBM_create(
        minDisparity=0, numDisparities=nd, blockSize=bs,
        P1=8 * bs * bs, P2=32 * bs * bs,  # smoothness penalties, OpenCV's recommended scale for 1 channel
        disp12MaxDiff=config.disp12_max_diff, preFilterCap=63, uniquenessRatio=config.uniqueness_ratio,
        speckleWindowSize=config.speckle_window, speckleRange=config.speckle_range,
        mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY,
    )
    disp = sgbm.compute(left, right).astype(np.float32) / 16.0  # fixed point, 4 fractional bits
    return disp


def depth_from_stereo(
    left_gray: np.ndarray,
    right_gray: np.ndarray,
    camera: PinholeCamera,
    num_disparities: int | None = None,
    block_size: int | None = None,
    max_depth: float | None = None,
    config: StereoDepthConfig = StereoDepthConfig(),
) -> np.ndarray:
    """Depth ``float32 (H, W)`` metres of the left rectified image from SGBM disparity; 0 = invalid.

    ``num_disparities``, ``block_size`` and ``max_depth`` override the matching fields of ``config``.
    ``camera`` must be the rectified (undistorted) left camera with ``baseline`` set.
    """
    B = _baseline(camera)
    over = {k: v for k, v in (("num_disparities", num_disparities), ("block_size", block_size),
                              ("max_depth", max_depth)) if v is not None}
    if over:
        config = StereoDepthConfig(**{**config.__dict__, **over})
    disp = disparity_sgbm(left_gray, right_gray, config)
    z_max = config.max_depth if config.max_depth is not None else default_max_depth(camera, config.min_disparity_px)
    valid = disp > 0.5
    depth = np.zeros(disp.shape, np.float32)
    depth[valid] = np.float32(camera.fx * B) / disp[valid]
    depth[depth > z_max] = 0.0
    b = config.border
    if b > 0:
        depth[:b], depth[-b:], depth[:, :b], depth[:, -b:] = 0.0, 0.0, 0.0, 0.0
    return depth


__all__ = ["StereoDepthConfig", "auto_num_disparities", "default_max_depth", "depth_from_stereo", "disparity_sgbm"]
