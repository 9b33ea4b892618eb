"""Configuration of the place-recognition stage (vocabulary, keyframe database, loop detector)."""
from __future__ import annotations

from dataclasses import dataclass

from vslam.errors import ConfigError


@dataclass(frozen=True)
class VocabularyConfig:
    """How a bag-of-binary-words vocabulary is trained (Galvez-Lopez & Tardos 2012, sec. IV).

    Attributes:
        k: branching factor of the vocabulary tree.
        levels: depth ``L`` of the tree; at most ``k**L`` words.
        max_iterations: k-majority iterations per node (stops earlier when assignments settle).
        seed: seed of the k-means++ seeding, so training is reproducible.
        direct_index_level: tree level (1 = children of the root) whose node ids form the
            "direct index" used to match features only within the same node.
    """

    k: int = 10
    levels: int = 4
    max_iterations: int = 10
    seed: int = 0
    direct_index_level: int = 2

    def __post_init__(self) -> None:
        if self.k < 2 or self.k > 20:
            raise ConfigError(f"vocabulary k={self.k}: the branching factor must be in 2..20")
        if self.levels < 1 or self.levels > 10:
            raise ConfigError(f"vocabulary levels={self.levels}: the depth must be in 1..10")
        if self.max_iterations < 1:
            raise ConfigError(f"vocabulary max_iterations={self.max_iterations}: must be >= 1")
        if not 1 <= self.direct_index_level <= self.levels:
            raise ConfigError(
                f"vocabulary direct_index_level={self.direct_index_level}: must be in 1..levels ({self.levels})"
            )


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


@dataclass(frozen=True)
class LoopDetectorConfig:
    """Loop candidate detection with temporal consistency (ORB-SLAM's consistency groups).

    Attributes:
        min_score: minimum normalized score of a candidate (see ``DatabaseConfig.normalize_with``).
        max_candidates: database results considered per query.
        group_radius: with no covisibility callback, keyframes whose ids differ by at most this are
            neighbours (they form a candidate's group).
        exclude_radius: with no covisible set given, keyframes whose ids are within this of the
            query id are excluded from the query (they are its temporal neighbours).
        min_consistent: a group must be found in this many consecutive queries to be accepted.
        accumulated_ratio: groups whose accumulated score is below this fraction of the best
            group's are dropped (ORB-SLAM uses 0.75).
    """

    min_score: float = 0.5
    max_candidates: int = 10
    group_radius: int = 20
    exclude_radius: int = 30
    min_consistent: int = 3
    accumulated_ratio: float = 0.75

    def __post_init__(self) -> None:
        if self.max_candidates < 1:
            raise ConfigError(f"loop max_candidates={self.max_candidates}: must be >= 1")
        if self.min_consistent < 1:
            raise ConfigError(f"loop min_consistent={self.min_consistent}: must be >= 1")
        if self.group_radius < 0 or self.exclude_radius < 0:
            raise ConfigError("loop group_radius/exclude_radius must be >= 0")
        if not 0.0 <= self.accumulated_ratio <= 1.0:
            raise ConfigError(f"loop accumulated_ratio={self.accumulated_ratio}: must be in [0, 1]")


@dataclass(frozen=True)
class LoopConfig:
    """All place-recognition settings."""

    vocabulary: VocabularyConfig = VocabularyConfig()
    database: DatabaseConfig = DatabaseConfig()
    detector: LoopDetectorConfig = LoopDetectorConfig()
