"""Configuration of the place-recognition stage (vocabulary, keyframe database, loop detector)."""
from __future__ import annotations

from dataclasses import dataclass

from vslam.errors import ConfigError
from vslam.map.config import DatabaseConfig  # the keyframe database is in map/; re-exported here


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
class ClosingConfig:
    """Geometric verification and correction of a loop candidate (ORB-SLAM, Mur-Artal et al. 2015,
    sec. VII-B/C/D; ORB-SLAM2 sec. VI-D).

    Attributes:
        candidate_neighbours: the candidate's strongest covisible keyframes whose points are matched
            together with its own.
        match_ratio: Lowe ratio of the brute-force descriptor matching (query keypoints vs points).
        max_descriptor_distance: Hamming bits; worse descriptor matches are dropped.
        min_matches: descriptor matches needed before RANSAC.
        align_threshold_m: RGB-D/stereo 3D-3D RANSAC inlier distance, metres (scaled by depth^2 for
            points beyond 1 m, as depth noise grows quadratically).
        align_threshold_rel: monocular Sim(3) RANSAC inlier distance as a fraction of the median
            distance of the matched points from the candidate camera.
        search_radius_px: guided matching (projection of the candidate's points at the estimated
            pose) search radius.
        min_inliers: inliers after guided matching and pose refinement needed to accept a loop
            (RGB-D / stereo).
        min_inliers_mono: the same for monocular.
        min_inlier_ratio: accepted loops also need this fraction of the guided matches as inliers.
        max_correction_deg / max_correction_m: a loop whose correction of the query pose is larger
            is rejected (a drift of this size is implausible between two consistent keyframes);
            ``max_correction_m`` is ignored for monocular (unknown scale).
        covisibility_edge_weight: covisibility links at least this strong enter the essential graph.
        loop_edge_information: information multiplier of the loop edges relative to the odometry
            (spanning tree, covisibility) edges: the verified loop pose is far more certain than one
            odometry step (it is measured against the old map directly).
        min_keyframes_between: no loop is detected within this many keyframes after the last one.
        connected_min_weight: keyframes sharing at least this many points with the query are its
            "connected" keyframes (ORB-SLAM: 15): excluded from the loop query and moved with it by a
            correction. Weaker covisibility links (old points re-observed on a revisit) are loop
            candidates.
        fuse_radius_px: search radius when fusing the candidate's points into the query's neighbours.
        global_ba: run a global bundle adjustment after the pose-graph correction.
        match_keypoints_with_depth: RGB-D / stereo: the candidate group's keypoints with depth but no
            (alive) map point join the verification's RANSAC, matched keyframe by keyframe: those of
            the candidate and its ``depth_keypoint_neighbours`` strongest covisible keyframes (each
            keyframe costs one brute-force matching).
        confirm_min_keyframes / confirm_min_inliers / confirm_max_m / confirm_max_deg: RGB-D
            loops below ``min_inliers`` (and single detections that temporal consistency has not
            confirmed) are accepted when they have ``confirm_min_inliers`` inliers and this many of the
            query's connected keyframes, verified against the same candidate group with as many
            inliers, agree on the correction within these bounds (ORB-SLAM3's covisibility check;
            :meth:`vslam.loop.closing.LoopCloser._confirmed`). 0 keyframes turns the rule off.
        confirm_neighbours: the query's strongest connected keyframes tried for that confirmation.
        refine_ransac_pose: refine the 3D-3D RANSAC pose on its inliers' reprojection errors before
            the guided matching (``refine_ransac`` of :func:`vslam.loop.verification.verify`).
        confirm_min_map_inliers: a loop accepted by confirmation also needs this many map-point
            inliers after guided matching and refinement (0: a RANSAC-only pose is accepted too).
        global_ba_weak_loops: run ``global_ba`` also after a loop accepted by confirmation (fewer than
            ``min_inliers`` map-point inliers). Off: such a loop keeps the essential graph's correction.
            With ~10 loop observations against thousands along the trajectory the global BA re-opens
            the loop: TUM fr3/cabinet (loop 57 -> 2, 10 inliers), error of the last keyframe relative
            to keyframe 2 (GT) 15 mm after the essential graph, 106 mm after the global BA (74 mm with
            no loop), ATE 0.032 -> 0.050 m (the same 0.050 without the essential graph first: it is
            the BA's optimum, not its initialization); u_right residual 0.026 -> 0.036.
    """

    candidate_neighbours: int = 10
    match_ratio: float = 0.8
    max_descriptor_distance: float = 64.0
    min_matches: int = 20
    align_threshold_m: float = 0.05
    align_threshold_rel: float = 0.03
    search_radius_px: float = 8.0
    min_inliers: int = 40
    min_inliers_mono: int = 40
    min_inlier_ratio: float = 0.3
    max_correction_deg: float = 45.0
    max_correction_m: float = 2.0
    covisibility_edge_weight: int = 100
    loop_edge_information: float = 10.0
    min_keyframes_between: int = 10
    connected_min_weight: int = 15
    fuse_radius_px: float = 4.0
    global_ba: bool = True
    match_keypoints_with_depth: bool = True
    depth_keypoint_neighbours: int = 10
    confirm_min_keyframes: int = 1
    confirm_min_inliers: int = 15
    confirm_max_m: float = 0.2
    confirm_max_deg: float = 4.0
    confirm_neighbours: int = 3
    refine_ransac_pose: bool = True
    confirm_min_map_inliers: int = 6
    global_ba_weak_loops: bool = False

    def __post_init__(self) -> None:
        if self.min_inliers < 6 or self.min_inliers_mono < 6:
            raise ConfigError(f"loop closing min_inliers={self.min_inliers}/{self.min_inliers_mono}: must be >= 6")
        if not 0.0 < self.match_ratio <= 1.0:
            raise ConfigError(f"loop closing match_ratio={self.match_ratio}: must be in (0, 1]")
        if self.confirm_min_keyframes < 0 or self.confirm_neighbours < 0 or self.depth_keypoint_neighbours < 0 \
                or self.confirm_min_map_inliers < 0:
            raise ConfigError("loop closing confirm_min_keyframes, confirm_neighbours, depth_keypoint_neighbours and "
                              "confirm_min_map_inliers must be >= 0")
        for name in ("align_threshold_m", "align_threshold_rel", "search_radius_px", "fuse_radius_px",
                     "confirm_max_m", "confirm_max_deg"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"loop closing {name}={getattr(self, name)}: must be > 0")


@dataclass(frozen=True)
class RelocalizationConfig:
    """Relocalization of a frame whose tracking failed (ORB-SLAM sec. V-C): BoW candidates, PnP
    RANSAC, guided matching and pose refinement.

    Attributes:
        max_candidates: keyframes (best raw BoW score first) tried.
        match_ratio / max_descriptor_distance: descriptor matching of the frame to a candidate's points.
        min_matches: matches needed to try PnP.
        reproj_px: PnP RANSAC inlier threshold.
        search_radius_px: guided matching radius at the PnP pose.
        min_inliers: inliers after refinement needed to accept the pose (ORB-SLAM: 50).
        recover_min_matches / recover_min_inliers: the tracker's fallback against its recent
            keyframes (:meth:`Relocalizer.recover`; candidates known, not from place recognition):
            descriptor matches to try RANSAC, map-point inliers after guided matching to accept.
        recover_covisible: covisible keyframes of each recent keyframe whose points join that search.
    """

    max_candidates: int = 5
    match_ratio: float = 0.8
    max_descriptor_distance: float = 64.0
    min_matches: int = 15
    reproj_px: float = 4.0
    search_radius_px: float = 8.0
    min_inliers: int = 40
    recover_min_matches: int = 10
    recover_min_inliers: int = 20
    recover_covisible: int = 5

    def __post_init__(self) -> None:
        if self.max_candidates < 1 or self.min_inliers < 6 or self.min_matches < 6:
            raise ConfigError("relocalization needs max_candidates >= 1, min_matches >= 6 and min_inliers >= 6")


@dataclass(frozen=True)
class LoopConfig:
    """All place-recognition and loop-closing settings (``enabled=false`` turns loop closing off)."""

    enabled: bool = True
    vocabulary: VocabularyConfig = VocabularyConfig()
    database: DatabaseConfig = DatabaseConfig()
    detector: LoopDetectorConfig = LoopDetectorConfig()
    closing: ClosingConfig = ClosingConfig()
    relocalization: RelocalizationConfig = RelocalizationConfig()
