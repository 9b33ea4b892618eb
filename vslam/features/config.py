"""Configuration of the feature layer: detection, descriptor matching, KLT tracking, stereo matching.

Each stage takes its own frozen dataclass; defaults are the values used on KITTI / TUM-sized images.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

from vslam.errors import ConfigError
from vslam.param import param

DETECTORS = ("orb", "sift", "akaze", "brisk", "gftt_orb")
SUBPIXEL_MODES = ("auto", "off", "cornersubpix", "parabola")


@dataclass(frozen=True)
class FeatureConfig:
    """Feature detection."""

    detector: str = param("orb", "orb (grid-distributed ORB over a pyramid), sift, akaze, brisk or gftt_orb (Shi-Tomasi corners + ORB descriptors)")
    n_features: int = param(2000, "features kept per frame (upper bound; low texture gives fewer)")
    scale_factor: float = param(1.2, "pyramid scale between consecutive levels (ORB, GFTT-ORB)")
    n_levels: int = param(8, "pyramid levels (ORB)")
    # Candidates are ranked by FAST score inside each grid cell, so a low threshold (10) keeps strong corners
    # first and still gives weak-texture cells a feature. 20 (ORB-SLAM's) returns ~2.5x fewer FAST corners, so
    # the detector is ~15-25% faster (its cost is mostly per returned corner), at equal or better ATE on
    # 7-Scenes RGB-D odometry (0.0553 vs 0.0586 m), fr1 desk (0.0038 vs 0.0045), KITTI 06 stereo (0.125 vs
    # 0.124), KITTI 07 mono (0.256 vs 0.276), worse on the fr3 cabinet keyframes (0.23 vs 0.20), with fewer
    # weak-texture cells covered (32 px cells: 53% vs 68% on 7-Scenes, 70% vs 83% on the brick texture).
    fast_threshold: int = param(10, "FAST intensity threshold of ORB candidates")
    # ORB-SLAM's 20/7 scheme. Measured on KITTI + TUM frames: 20/7 covers 97%/68% of 40 px cells vs 96%/61%
    # for a single pass at 10, but costs ~20-25% more time, so it is off by default.
    min_fast_threshold: int = param(0, "if > 0 (and < fast_threshold): FAST again at this threshold in cells where fast_threshold found nothing")
    cell_size: int = param(32, "grid cell side in pixels at each pyramid level, used to spread features")
    edge_threshold: int = param(19, "keypoints closer than this to a level's border are dropped (rotated BRIEF needs ~19 px)")
    patch_size: int = param(31, "ORB patch (orientation and descriptor) diameter in pixels")
    sift_contrast_threshold: float = param(0.02, "SIFT's contrast threshold")
    akaze_threshold: float = param(0.0005, "AKAZE detector threshold")
    brisk_threshold: int = param(20, "BRISK AGAST threshold")
    gftt_quality: float = param(0.001, "Shi-Tomasi quality level (gftt_orb)")
    gftt_min_distance: float = param(8.0, "minimum distance between Shi-Tomasi corners in pixels (gftt_orb)")
    # issue #24 item 3: cornersubpix keeps cv2.cornerSubPix's shift only within half a pixel of the FAST corner (a
    # FAST corner is not always a gradient-orthogonal corner); parabola interpolates the Shi-Tomasi response's peak
    # around it (at most half a pixel by construction). `auto` (the default) is parabola for stereo and RGB-D (it
    # improved every real stereo and RGB-D row: benchmarks/RESULTS.md, "issue #24 item 3") and off for monocular (it
    # made KITTI 07 mono worse on four start frames of five) and the inertial sensors (stereo-inertial MH_01 80:
    # 0.00288 -> 0.00300 m, worse at each of 8 keyframe ratios tried); :meth:`FeatureConfig.for_sensor` resolves it.
    subpixel: str = param("auto", "ORB: refine each FAST corner to sub-pixel accuracy on its pyramid level: auto (parabola for stereo and RGB-D, off for monocular and the inertial sensors), off, cornersubpix (cv2.cornerSubPix) or parabola (peak of the Shi-Tomasi response, a parabola per axis)")
    subpixel_window: int = param(2, "half side of cornerSubPix's search window, level pixels", bounds="[1, 15]")
    subpixel_min_octave: int = param(0, "only keypoints of pyramid levels from this one up are refined (0: every level)", bounds="[0, 31]")
    subpixel_max_octave: int = param(31, "only keypoints of pyramid levels up to this one are refined (0: the full-resolution level only)", bounds="[0, 31]")

    def __post_init__(self) -> None:
        if self.detector not in DETECTORS:
            raise ConfigError(f"features.detector={self.detector!r} is unknown; use one of {DETECTORS}")
        if str(self.subpixel).lower() == "false":  # YAML reads an unquoted `off` (or `false`) as a boolean
            object.__setattr__(self, "subpixel", "off")
        if self.subpixel not in SUBPIXEL_MODES:
            raise ConfigError(f"features.subpixel={self.subpixel!r} must be one of {', '.join(SUBPIXEL_MODES)}")
        if self.n_features < 1:
            raise ConfigError(f"features.n_features={self.n_features} must be >= 1")
        if not self.scale_factor > 1.0:
            raise ConfigError(f"features.scale_factor={self.scale_factor} must be > 1")
        if self.n_levels < 1:
            raise ConfigError(f"features.n_levels={self.n_levels} must be >= 1")
        if self.cell_size < 4:
            raise ConfigError(f"features.cell_size={self.cell_size} must be >= 4 pixels")
        if self.patch_size % 2 == 0 or self.patch_size < 7:
            raise ConfigError(f"features.patch_size={self.patch_size} must be odd and >= 7")

    def for_sensor(self, sensor: str) -> FeatureConfig:
        """This configuration with ``subpixel: auto`` resolved for ``sensor`` (``mono``, ``stereo``,
        ``rgbd``, or one of them with ``-inertial``): ``parabola`` for stereo and RGB-D, ``off`` for
        monocular and the inertial sensors. A detector given an unresolved ``auto`` refines nothing."""
        if self.subpixel != "auto":
            return self
        mode = "parabola" if sensor in ("stereo", "rgbd") else "off"
        return replace(self, subpixel=mode)


@dataclass(frozen=True)
class MatcherConfig:
    """Descriptor matching."""

    ratio: float = param(0.8, "Lowe's ratio test: best < ratio * second best (1.0 disables it)")
    mutual: bool = param(True, "keep only mutual nearest neighbours")
    # ORB-SLAM uses 50 (TH_LOW) / 100 (TH_HIGH) for 256-bit ORB.
    max_distance: float | None = param(None, "absolute bound on the best distance (Hamming bits or L2); null: no bound")
    # on a busy 2-core machine 2 threads made a 2000x2000 match 3-10x slower (spinning)
    num_threads: int = param(1, "OpenMP threads faiss may use (results do not depend on it)")
    use_faiss: bool = param(True, "fast search: binary descriptors by the compiled one-pass matcher, float ones by faiss k-NN; false: NumPy brute force")

    def __post_init__(self) -> None:
        if not 0.0 < self.ratio <= 1.0:
            raise ConfigError(f"matcher.ratio={self.ratio} must be in (0, 1]")
        if self.num_threads < 1:
            raise ConfigError(f"matcher.num_threads={self.num_threads} must be >= 1")


@dataclass(frozen=True)
class KLTConfig:
    """Pyramidal Lucas-Kanade tracking (Bouguet 2001) with a forward-backward check."""

    win_size: int = param(21, "LK window side in pixels")
    max_level: int = param(3, "pyramid levels above the base (3 -> 4 levels)")
    max_iter: int = param(30, "LK iterations per level")
    eps: float = param(0.01, "LK convergence threshold per level")
    fb_threshold: float = param(1.0, "max forward-backward error in pixels (Kalal et al. 2010); <= 0 disables")
    border: float = param(2.0, "tracked points closer than this to the image border are rejected, pixels")
    min_eig_threshold: float = param(1e-4, "OpenCV's minimum eigenvalue threshold (rejects flat patches)")

    def __post_init__(self) -> None:
        if self.win_size < 3 or self.win_size % 2 == 0:
            raise ConfigError(f"klt.win_size={self.win_size} must be odd and >= 3")
        if self.max_level < 0:
            raise ConfigError(f"klt.max_level={self.max_level} must be >= 0")
