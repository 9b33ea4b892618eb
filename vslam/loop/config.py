"""Configuration of the place-recognition stage (vocabulary, keyframe database, loop detector)."""
from __future__ import annotations

from dataclasses import dataclass

from vslam.errors import ConfigError
from vslam.map.config import DatabaseConfig  # the keyframe database is in map/; re-exported here
from vslam.param import param, section


@dataclass(frozen=True)
class VocabularyConfig:
    """How a bag-of-binary-words vocabulary is trained (Galvez-Lopez & Tardos 2012, sec. IV)."""

    k: int = param(10, "branching factor of the vocabulary tree", bounds="[2, 256]")
    levels: int = param(4, "depth L of the tree; at most k**L words", bounds="[1, 10]")
    max_iterations: int = param(10, "k-majority iterations per node (stops earlier when assignments settle)", bounds="[1, 10000]")
    seed: int = param(0, "seed of the k-means++ seeding (reproducible training)", bounds="[0, 4294967295]")
    direct_index_level: int = param(2, "tree level (1 = the root's children) whose nodes form the direct index used to match features", bounds="[0, 10]")

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
class LoopDetectorConfig:
    """Loop candidate detection with temporal consistency (ORB-SLAM's consistency groups)."""

    min_score: float = param(0.5, "minimum normalized score of a candidate (see database.normalize_with)", bounds="[0, 1000]")
    max_candidates: int = param(10, "database results considered per query", bounds="[1, 10000]")
    group_radius: int = param(20, "with no covisibility callback, keyframes whose ids differ by at most this form a group", bounds="[0, 1000000]")
    exclude_radius: int = param(30, "with no covisible set, keyframes with ids within this of the query are excluded", bounds="[0, 1000000]")
    min_consistent: int = param(3, "a group must be found in this many consecutive queries to be accepted", bounds="[0, 1000]")
    accumulated_ratio: float = param(0.75, "groups below this fraction of the best group's accumulated score are dropped (ORB-SLAM: 0.75)", bounds="[0, 1]")

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
class LoopFuseConfig:
    """Fusing a verified loop's candidate points into the query's neighbours (ORB-SLAM's SearchAndFuse)."""

    radius_px: float = param(4.0, "search radius when fusing the candidate's points into the query's neighbours, pixels", bounds="(0, 10000]")
    max_descriptor_distance: float = param(50.0, "Hamming bound of that fusion's guided matching", bounds="[0, 1000000]")
    ratio: float = param(0.9, "ratio test of that fusion's guided matching", bounds="(0, 1]")

    def __post_init__(self) -> None:
        if not self.radius_px > 0:
            raise ConfigError(f"loop closing fuse.radius_px={self.radius_px}: must be > 0")


@dataclass(frozen=True)
class ConfirmConfig:
    """ORB-SLAM3's covisibility check (:meth:`vslam.loop.closing.LoopCloser._confirmed`): RGB-D loops below
    ``min_inliers`` (and single detections not yet temporally consistent) are accepted when they have
    ``confirm.min_inliers`` inliers and ``confirm.min_keyframes`` of the query's connected keyframes,
    verified against the same candidate group with as many inliers, agree on the correction within
    ``max_m`` / ``max_deg``."""

    min_keyframes: int = param(1, "connected keyframes that must confirm a weak RGB-D loop (0: rule off)", bounds="[0, 1000]")
    min_inliers: int = param(15, "inliers a weak RGB-D loop and each confirming keyframe need", bounds="[0, 1000000]")
    max_m: float = param(0.2, "confirming corrections agree within this translation, metres", bounds="[0, 1000000]")
    max_deg: float = param(4.0, "confirming corrections agree within this rotation, degrees", bounds="[0, 180]")
    neighbours: int = param(3, "the query's strongest connected keyframes tried for that confirmation", bounds="[0, 1000]")
    min_map_inliers: int = param(6, "a confirmed loop also needs this many map-point inliers after refinement (0: RANSAC-only ok)", bounds="[0, 1000000]")

    def __post_init__(self) -> None:
        if self.min_keyframes < 0 or self.neighbours < 0 or self.min_map_inliers < 0:
            raise ConfigError("loop closing confirm.min_keyframes, confirm.neighbours and confirm.min_map_inliers must be >= 0")
        for name in ("max_m", "max_deg"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"loop closing confirm.{name}={getattr(self, name)}: must be > 0")


@dataclass(frozen=True)
class ClosingConfig:
    """Geometric verification and correction of a loop candidate (ORB-SLAM, Mur-Artal et al. 2015,
    sec. VII-B/C/D; ORB-SLAM2 sec. VI-D)."""

    candidate_neighbours: int = param(10, "the candidate's strongest covisible keyframes whose points are matched with its own", bounds="[0, 10000]")
    match_ratio: float = param(0.8, "Lowe ratio of the brute-force descriptor matching (query keypoints vs points)", bounds="(0, 1]")
    max_descriptor_distance: float = param(64.0, "Hamming bits; worse descriptor matches are dropped", bounds="[0, 1000000]")
    min_matches: int = param(20, "descriptor matches needed before RANSAC", bounds="[3, 1000000]")
    align_threshold_m: float = param(0.05, "RGB-D/stereo 3D-3D RANSAC inlier distance, metres (times depth^2 beyond 1 m)", bounds="(0, 1000000]")
    align_threshold_rel: float = param(0.09, "monocular Sim(3) RANSAC inlier distance, fraction of the matched map points' median distance from their median point", bounds="(0, 1000]")
    search_radius_px: float = param(8.0, "guided matching radius at the estimated pose, pixels", bounds="(0, 10000]")
    min_inliers: int = param(40, "inliers after guided matching and refinement needed to accept a loop (RGB-D / stereo)", bounds="[3, 1000000]")
    min_inliers_mono: int = param(40, "the same for monocular", bounds="[3, 1000000]")
    merge_scale_min_pairs: int = param(20, "monocular segment join: verified pairs with a query-side point needed to take the join's scale as their median depth ratio (else the RANSAC scale)", bounds="[1, 1000000]")
    min_inlier_ratio: float = param(0.3, "accepted loops also need this fraction of the guided matches as inliers", bounds="[0, 1]")
    max_correction_deg: float = param(45.0, "a loop correcting the query pose by more than this rotation is rejected, degrees", bounds="[0, 180]")
    max_correction_m: float = param(2.0, "the same for translation, metres (ignored for monocular: unknown scale)", bounds="[0, 1000000]")
    covisibility_edge_weight: int = param(100, "covisibility links at least this strong enter the essential graph", bounds="[0, 1000000]")
    # the verified loop pose is far more certain than one odometry step (it is measured against the old map)
    loop_edge_information: float = param(10.0, "information multiplier of loop edges relative to odometry edges", bounds="(0, 1e12]")
    min_keyframes_between: int = param(10, "no loop is detected within this many keyframes after the last one", bounds="[0, 1000000]")
    # Weaker covisibility links (old points re-observed on a revisit) are loop candidates.
    connected_min_weight: int = param(15, "keyframes sharing this many points with the query are connected: excluded and moved with it (ORB-SLAM: 15)", bounds="[0, 1000000]")
    max_tries: int = param(3, "keyframes of a consistent candidate group verified at most (best match first)", bounds="[1, 1000]")
    guided_max_descriptor_distance: float = param(64.0, "Hamming bound of the verification's guided matching", bounds="[0, 1000000]")
    guided_ratio: float = param(0.9, "ratio test of the verification's guided matching", bounds="(0, 1]")
    min_search_radius_px: float = param(3.0, "the second guided matching uses max(search_radius_px / 2, this), pixels", bounds="[0, 10000]")
    global_ba: bool = param(True, "run a global bundle adjustment after the pose-graph correction")
    match_keypoints_with_depth: bool = param(True, "RGB-D/stereo: the candidate group's keypoints with depth but no map point join the RANSAC")
    depth_keypoint_neighbours: int = param(10, "strongest covisible keyframes of the candidate whose depth keypoints join (one matching each)", bounds="[0, 10000]")
    refine_ransac_pose: bool = param(True, "refine the 3D-3D RANSAC pose on its inliers' reprojection errors before guided matching")
    # With ~10 loop observations against thousands along the trajectory the global BA re-opens the loop: TUM
    # fr3/cabinet (loop 57 -> 2, 10 inliers), error of the last keyframe relative to keyframe 2 (GT) 15 mm after
    # the essential graph, 106 mm after the global BA (74 mm with no loop), ATE 0.032 -> 0.050 m (the same
    # 0.050 without the essential graph first: it is the BA's optimum, not its initialization); u_right
    # residual 0.026 -> 0.036.
    global_ba_weak_loops: bool = param(False, "run global_ba also after a loop accepted by confirmation (off: keep the essential graph's correction)")
    fuse: LoopFuseConfig = section(LoopFuseConfig, "fusing the candidate's points into the query's neighbours", ("fuse_",))
    confirm: ConfirmConfig = section(ConfirmConfig, "confirmation of weak RGB-D loops by connected keyframes", ("confirm_",))

    def __post_init__(self) -> None:
        if self.min_inliers < 6 or self.min_inliers_mono < 6:
            raise ConfigError(f"loop closing min_inliers={self.min_inliers}/{self.min_inliers_mono}: must be >= 6")
        if not 0.0 < self.match_ratio <= 1.0:
            raise ConfigError(f"loop closing match_ratio={self.match_ratio}: must be in (0, 1]")
        if self.depth_keypoint_neighbours < 0:
            raise ConfigError("loop closing depth_keypoint_neighbours must be >= 0")
        for name in ("align_threshold_m", "align_threshold_rel", "search_radius_px"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"loop closing {name}={getattr(self, name)}: must be > 0")


@dataclass(frozen=True)
class RelocalizationConfig:
    """Relocalization of a frame whose tracking failed (ORB-SLAM sec. V-C): BoW candidates, PnP
    RANSAC, guided matching and pose refinement."""

    max_candidates: int = param(5, "keyframes tried (best raw BoW score first)", bounds="[1, 10000]")
    match_ratio: float = param(0.8, "Lowe ratio of the frame-to-candidate descriptor matching", bounds="(0, 1]")
    max_descriptor_distance: float = param(64.0, "Hamming bound of the frame-to-candidate descriptor matching", bounds="[0, 1000000]")
    min_matches: int = param(15, "matches needed to try PnP", bounds="[3, 1000000]")
    candidate_covisible: int = param(10, "strongest covisible keyframes of a candidate whose points join its matching", bounds="[0, 10000]")
    reproj_px: float = param(4.0, "PnP RANSAC inlier threshold, pixels", bounds="(0, 10000]")
    search_radius_px: float = param(8.0, "guided matching radius at the PnP pose, pixels", bounds="(0, 10000]")
    min_inliers: int = param(40, "inliers after refinement needed to accept the pose (ORB-SLAM: 50)", bounds="[3, 1000000]")
    recover_min_matches: int = param(10, "tracker fallback against its recent keyframes: descriptor matches to try RANSAC", bounds="[3, 1000000]")
    recover_min_inliers: int = param(20, "tracker fallback: map-point inliers after guided matching to accept", bounds="[3, 1000000]")
    recover_covisible: int = param(5, "tracker fallback: covisible keyframes of each recent keyframe whose points join", bounds="[0, 10000]")

    def __post_init__(self) -> None:
        if self.max_candidates < 1 or self.min_inliers < 6 or self.min_matches < 6:
            raise ConfigError("relocalization needs max_candidates >= 1, min_matches >= 6 and min_inliers >= 6")


@dataclass(frozen=True)
class LoopConfig:
    """All place-recognition and loop-closing settings."""

    enabled: bool = param(True, "run place recognition and loop closing (false: off)")
    vocabulary: VocabularyConfig = section(VocabularyConfig, "bag-of-words vocabulary training")
    database: DatabaseConfig = section(DatabaseConfig, "keyframe database queries")
    detector: LoopDetectorConfig = section(LoopDetectorConfig, "loop candidate detection")
    closing: ClosingConfig = section(ClosingConfig, "loop verification and correction")
    relocalization: RelocalizationConfig = section(RelocalizationConfig, "relocalization of lost frames")
