"""Settings of the kernels in ``map/`` that several stages share: the pose-graph solver (loop
closing; exposed as ``backend.pose_graph``) and the keyframe database (``loop.database``)."""
from __future__ import annotations

from dataclasses import dataclass

from vslam.errors import ConfigError


@dataclass(frozen=True)
class PoseGraphConfig:
    """SE(3) / Sim(3) pose-graph optimization (essential graph, ORB-SLAM2 Sec. VI-D).

    Attributes:
        max_iterations: LM iterations.
        relative_tolerance: LM relative error tolerance.
        default_sigma_rotation: radians, edge std used when an edge gives no information.
        default_sigma_translation: metres, idem.
        default_sigma_scale: log-scale std of Sim(3) edges without information.
        prior_sigma: std of the priors that hold fixed nodes (tiny = fixed).
    """

    max_iterations: int = 100
    relative_tolerance: float = 1e-8
    default_sigma_rotation: float = 0.01
    default_sigma_translation: float = 0.05
    default_sigma_scale: float = 0.01
    prior_sigma: float = 1e-6

    def __post_init__(self) -> None:
        if self.max_iterations < 1:
            raise ConfigError(f"pose graph max_iterations must be >= 1, got {self.max_iterations}")
        for name in ("default_sigma_rotation", "default_sigma_translation", "default_sigma_scale", "prior_sigma"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"pose graph config {name} must be > 0, got {getattr(self, name)}")



@dataclass(frozen=True)
class DatabaseConfig:
    """Keyframe database query settings.

    Attributes:
        normalize_with: how raw scores are normalized: ``"max"`` divides by the best raw score of
            the query against its excluded (covisible) keyframes, ``"min"`` by the lowest of those
            (ORB-SLAM's ``minScore``), ``"none"`` keeps raw L1 scores.
        subtract_baseline: subtract the query's chance-level score (the median raw score over the
            non-excluded keyframes) from raw and reference scores before dividing. With a small
            vocabulary (the embedded default has 10^4 words) two unrelated images share many
            words and score ~0.13; without this the ratio barely separates loops from chance.
            Set False for plain DBoW2/ORB-SLAM behaviour.
        min_baseline_keyframes: with ``subtract_baseline``, scores are normalized only once at
            least this many non-excluded keyframes give a baseline (before that, raw scores).
        min_common_words_ratio: keep only keyframes that share at least this fraction of the
            largest number of words any keyframe shares with the query (ORB-SLAM uses 0.8).
        merge_every: pending (recently added) keyframes are merged into the compressed inverted
            index once there are this many (or 1/16 of the merged ones, whichever is more).
    """

    normalize_with: str = "max"
    subtract_baseline: bool = True
    min_baseline_keyframes: int = 8
    min_common_words_ratio: float = 0.0
    merge_every: int = 32

    def __post_init__(self) -> None:
        if self.normalize_with not in ("max", "min", "none"):
            raise ConfigError(f"database normalize_with={self.normalize_with!r}: use 'max', 'min' or 'none'")
        if not 0.0 <= self.min_common_words_ratio <= 1.0:
            raise ConfigError(f"database min_common_words_ratio={self.min_common_words_ratio}: must be in [0, 1]")
        if self.merge_every < 1:
            raise ConfigError(f"database merge_every={self.merge_every}: must be >= 1")
