"""Settings of the kernels in ``map/`` that several stages share: the pose-graph solver (loop
closing; exposed as ``backend.pose_graph``) and the keyframe database (``loop.database``)."""
from __future__ import annotations

from dataclasses import dataclass

from vslam.errors import ConfigError
from vslam.param import param


@dataclass(frozen=True)
class PoseGraphConfig:
    """SE(3) / Sim(3) pose-graph optimization (essential graph, ORB-SLAM2 Sec. VI-D)."""

    max_iterations: int = param(100, "LM iterations", bounds="[1, 100000]")
    relative_tolerance: float = param(1e-8, "LM relative error tolerance", bounds="[0, 1]")
    default_sigma_rotation: float = param(0.01, "radians; edge rotation std when an edge gives no information", bounds="(0, 1000]")
    default_sigma_translation: float = param(0.05, "metres; edge translation std when an edge gives no information", bounds="(0, 1000000]")
    default_sigma_scale: float = param(0.01, "log-scale std of Sim(3) edges without information", bounds="(0, 1000]")
    prior_sigma: float = param(1e-6, "std of the priors that hold fixed nodes (tiny = fixed)", bounds="(0, 1000]")

    def __post_init__(self) -> None:
        if self.max_iterations < 1:
            raise ConfigError(f"pose graph max_iterations must be >= 1, got {self.max_iterations}")
        for name in ("default_sigma_rotation", "default_sigma_translation", "default_sigma_scale", "prior_sigma"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"pose graph config {name} must be > 0, got {getattr(self, name)}")


@dataclass(frozen=True)
class DatabaseConfig:
    """Keyframe database query settings."""

    normalize_with: str = param("max", "scores divided by the best (max) or lowest (min, ORB-SLAM minScore) score against the covisible keyframes, or none")
    # With a small vocabulary (the embedded default has 10^4 words) two unrelated images share many words and
    # score ~0.13; without this the ratio barely separates loops from chance. False: plain DBoW2/ORB-SLAM.
    subtract_baseline: bool = param(True, "subtract the query's chance-level score (median over non-excluded keyframes) before dividing")
    min_baseline_keyframes: int = param(8, "with subtract_baseline, normalize only once this many keyframes give a baseline", bounds="[0, 1000000]")
    min_common_words_ratio: float = param(0.0, "keep keyframes sharing at least this fraction of the most words any keyframe shares (ORB-SLAM: 0.8)", bounds="[0, 1]")
    merge_every: int = param(32, "pending keyframes merge into the compressed inverted index once there are this many (or 1/16 of the merged)", bounds="[1, 1000000]")

    def __post_init__(self) -> None:
        if self.normalize_with not in ("max", "min", "none"):
            raise ConfigError(f"database normalize_with={self.normalize_with!r}: use 'max', 'min' or 'none'")
        if not 0.0 <= self.min_common_words_ratio <= 1.0:
            raise ConfigError(f"database min_common_words_ratio={self.min_common_words_ratio}: must be in [0, 1]")
        if self.merge_every < 1:
            raise ConfigError(f"database merge_every={self.merge_every}: must be >= 1")
