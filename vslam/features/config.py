"""Configuration of the feature layer: detection, descriptor matching, KLT tracking, stereo matching.

Each stage takes its own frozen dataclass; defaults are the values used on KITTI / TUM-sized images.
"""
from __future__ import annotations

from dataclasses import dataclass

from vslam.errors import ConfigError

DETECTORS = ("orb", "sift", "akaze", "brisk", "gftt_orb")


@dataclass(frozen=True)
class FeatureConfig:
    """Feature detection.

    Attributes:
        detector: one of ``orb`` (grid-distributed ORB over a pyramid, the default), ``sift``,
            ``akaze``, ``brisk`` or ``gftt_orb`` (Shi-Tomasi corners with ORB descriptors, the same
            corners KLT tracks well).
        n_features: how many features to keep per frame (upper bound; low texture gives fewer).
        scale_factor: pyramid scale between consecutive levels (ORB, GFTT-ORB).
        n_levels: pyramid levels (ORB).
        fast_threshold: FAST intensity threshold for ORB candidates. Candidates are ranked by
            FAST score inside each grid cell, so a low threshold (10) keeps strong corners first
            and still gives weak-texture cells a feature. 20 (ORB-SLAM's) returns ~2.5x fewer
            FAST corners, so the detector is ~15-25% faster (its cost is mostly per returned
            corner), at equal or better ATE on 7-Scenes RGB-D odometry (0.0553 vs 0.0586 m), fr1
            desk (0.0038 vs 0.0045), KITTI 06 stereo (0.125 vs 0.124), KITTI 07 mono (0.256 vs
            0.276), worse on the fr3 cabinet keyframes (0.23 vs 0.20), with fewer weak-texture cells
            covered (32 px cells: 53% vs 68% on 7-Scenes, 70% vs 83% on the brick texture).
        min_fast_threshold: if > 0 (and < ``fast_threshold``), FAST runs again at this
            threshold in the grid cells where ``fast_threshold`` found nothing (ORB-SLAM's 20/7
            scheme). Measured on KITTI + TUM frames: 20/7 covers 97%/68% of 40 px cells vs
            96%/61% for a single pass at 10, but costs ~20-25% more time, so it is off by default.
        cell_size: grid cell side in pixels *at each pyramid level* used to spread features.
        edge_threshold: keypoints closer than this to a level's border are dropped (the rotated
            BRIEF pattern needs ~19 px).
        patch_size: ORB patch (orientation and descriptor) diameter.
        sift_contrast_threshold: SIFT's contrast threshold.
        akaze_threshold: AKAZE detector threshold.
        brisk_threshold: BRISK AGAST threshold.
        gftt_quality: Shi-Tomasi quality level for ``gftt_orb``.
        gftt_min_distance: minimum distance between Shi-Tomasi corners for ``gftt_orb``.
    """

    detector: str = "orb"
    n_features: int = 2000
    scale_factor: float = 1.2
    n_levels: int = 8
    fast_threshold: int = 10
    min_fast_threshold: int = 0
    cell_size: int = 32
    edge_threshold: int = 19
    patch_size: int = 31
    sift_contrast_threshold: float = 0.02
    akaze_threshold: float = 0.0005
    brisk_threshold: int = 20
    gftt_quality: float = 0.001
    gftt_min_distance: float = 8.0

    def __post_init__(self) -> None:
        if self.detector not in DETECTORS:
            raise ConfigError(f"features.detector={self.detector!r} is unknown; use one of {DETECTORS}")
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


@dataclass(frozen=True)
class MatcherConfig:
    """Descriptor matching.

    Attributes:
        ratio: Lowe's ratio test, best < ratio * second best (1.0 disables it).
        mutual: keep only mutual nearest neighbours.
        max_distance: absolute bound on the best distance (Hamming bits or L2); None = no bound.
            ORB-SLAM uses 50 (TH_LOW) / 100 (TH_HIGH) for 256-bit ORB.
        num_threads: OpenMP threads faiss may use (results do not depend on it). 1 by default:
            on a busy 2-core machine 2 threads made a 2000x2000 match 3-10x slower (spinning).
        use_faiss: use faiss for the k-NN search (faster than OpenCV's BFMatcher at >= a few
            hundred descriptors); False uses a NumPy brute force (reference implementation).
    """

    ratio: float = 0.8
    mutual: bool = True
    max_distance: float | None = None
    num_threads: int = 1
    use_faiss: bool = True

    def __post_init__(self) -> None:
        if not 0.0 < self.ratio <= 1.0:
            raise ConfigError(f"matcher.ratio={self.ratio} must be in (0, 1]")
        if self.num_threads < 1:
            raise ConfigError(f"matcher.num_threads={self.num_threads} must be >= 1")


@dataclass(frozen=True)
class KLTConfig:
    """Pyramidal Lucas-Kanade tracking (Bouguet 2001) with a forward-backward check.

    Attributes:
        win_size: LK window side in pixels.
        max_level: pyramid levels above the base (3 -> 4 levels).
        max_iter, eps: LK termination per level.
        fb_threshold: max forward-backward error in pixels (Kalal et al. 2010); <= 0 disables.
        border: tracked points closer than this to the image border are rejected.
        min_eig_threshold: OpenCV's minimum eigenvalue threshold (rejects flat patches).
    """

    win_size: int = 21
    max_level: int = 3
    max_iter: int = 30
    eps: float = 0.01
    fb_threshold: float = 1.0
    border: float = 2.0
    min_eig_threshold: float = 1e-4

    def __post_init__(self) -> None:
        if self.win_size < 3 or self.win_size % 2 == 0:
            raise ConfigError(f"klt.win_size={self.win_size} must be odd and >= 3")
        if self.max_level < 0:
            raise ConfigError(f"klt.max_level={self.max_level} must be >= 0")


@dataclass(frozen=True)
class StereoConfig:
    """Left-right matching of a rectified stereo pair (ORB-SLAM2's ``ComputeStereoMatches``).

    Attributes:
        max_row_diff: allowed row difference in pixels at level 0, multiplied by the right
            keypoint's octave scale.
        min_disparity: smallest accepted disparity in pixels (> 0 keeps depth finite).
        max_disparity: largest accepted disparity in pixels; None = ``fx * baseline / min_depth``
            when a camera is given, else the image width.
        min_depth: used to derive ``max_disparity`` from a camera (metres).
        max_distance: descriptor distance bound (Hamming bits for binary, L2 otherwise); None =
            100 bits for binary (ORB-SLAM's TH_HIGH) and no bound for float descriptors.
        ratio: best < ratio * second-best among the row candidates (1.0 disables).
        octave_tolerance: right keypoints must lie within this many octaves of the left one.
        refine: sub-pixel refinement by SAD block matching along the row plus a parabola fit.
        sad_window: half size of the SAD patch (5 -> 11x11) at the keypoint's octave.
        sad_search: half range of the SAD search along the row, in level pixels.
        subpixel: ``"parabola"`` (ORB-SLAM2: parabola through the SAD minimum, ~0.2-0.3 px
            bias on clean shifts) or ``"lk"`` (then a 1-D Lucas-Kanade refinement at full
            resolution, ~0.05 px).
        lk_window: half size of the full-resolution LK window (5 -> 11x11).
    """

    max_row_diff: float = 2.0
    min_disparity: float = 0.5
    max_disparity: float | None = None
    min_depth: float = 0.5
    max_distance: float | None = None
    ratio: float = 0.9
    octave_tolerance: int = 1
    refine: bool = True
    sad_window: int = 5
    sad_search: int = 5
    subpixel: str = "lk"
    lk_window: int = 5

    def __post_init__(self) -> None:
        if self.subpixel not in ("parabola", "lk"):
            raise ConfigError(f"stereo.subpixel={self.subpixel!r} must be 'parabola' or 'lk'")
        if self.max_row_diff <= 0:
            raise ConfigError(f"stereo.max_row_diff={self.max_row_diff} must be > 0")
        if self.min_disparity < 0:
            raise ConfigError(f"stereo.min_disparity={self.min_disparity} must be >= 0")
        if self.sad_window < 1 or self.sad_search < 1:
            raise ConfigError("stereo.sad_window and stereo.sad_search must be >= 1")
