"""Configuration of the visual-odometry frontend (association, motion estimation, keyframes, map).

One nested frozen dataclass per concern (``frontend.keyframes.*``, ``frontend.tracking.*`` ...);
every field is declared with :func:`~vslam.param.param` and its one-line doc (``vslam config``
lists them). Longer measurement notes behind a default are comments above the field.
"""
from __future__ import annotations

from dataclasses import dataclass

from vslam.errors import ConfigError
from vslam.param import param, section

ASSOCIATIONS = ("match", "track")
MOTIONS = ("3d2d", "3d3d", "2d2d")
SENSORS = ("mono", "stereo", "rgbd")
STEREO_FLOWS = ("lk2d", "row")


@dataclass(frozen=True)
class DepthConfig:
    """Which depth (RGB-D) and stereo measurements the frontend uses."""

    min_depth: float = param(0.1, "metres; nearer depth / stereo points are ignored", bounds="[0, 1000]")
    max_depth: float = param(10.0, "metres; farther RGB-D depths are ignored", bounds="(0, 1000000]")
    stereo_max_depth_baselines: float = param(60.0, "stereo points farther than this many baselines are 'far' (no depth)", bounds="(0, 1000000]")
    stereo_max_dy: float = param(1.5, "px; rows of a rectified stereo match must agree within this (stereo_flow lk2d)", bounds="[0, 1000]")
    stereo_flow: str = param("row", "stereo matches: row (pyramidal LK along the row; KITTI 06 / EuRoC ATE 0.0500 / 0.00069 m at 13-20 % less CPU) or lk2d (OpenCV 2-D pyramidal LK, before: 0.0558 / 0.00086 m)")
    stereo_flow_window: int = param(9, "window side of the left-to-right pyramidal LK that finds stereo matches, pixels (11 before row became the default)", bounds="[3, 101]")
    stereo_flow_levels: int = param(4, "pyramid levels above the base of that LK", bounds="[0, 16]")
    stereo_flow_max_iter: int = param(5, "LK iterations per level (the row refinement sets the final disparity)", bounds="[1, 1000]")
    stereo_flow_eps: float = param(0.1, "LK convergence threshold per level", bounds="(0, 100]")
    stereo_flow_min_zncc: float = param(0.5, "row: least normalized cross-correlation of a match's windows (rejects wrong minima)", bounds="[-1, 1]")


@dataclass(frozen=True)
class TrackingConfig:
    """Pose estimation of each frame against the local map, and when a frame counts as lost."""

    pnp_reproj_px: float = param(3.0, "PnP RANSAC / pose refinement inlier threshold in pixels", bounds="(0, 1000]")
    pnp_iterations: int = param(100, "PnP RANSAC iterations", bounds="[1, 100000]")
    # 7-Scenes odometry ATE 0.32 vs 0.055 m: fast motions mislead it.
    pose_from_prediction: bool = param(False, "skip PnP RANSAC when the robust refinement from the motion prediction holds")
    align_inlier_m: float = param(0.03, "3D-3D RANSAC threshold at 1 m depth, metres (scaled with depth^2 for RGB-D noise)", bounds="(0, 1000]")
    min_inliers: int = param(20, "fewer pose inliers than this means the frame is lost", bounds="[6, 100000]")
    essential_px: float = param(1.0, "2D-2D (essential matrix) RANSAC threshold in pixels", bounds="(0, 1000]")
    max_lost_frames: int = param(3, "after this many consecutive lost frames, re-initialize a new map segment", bounds="[0, 1000000]")
    # ORB-SLAM3 keeps relocalizing a lost monocular camera for 3 s before it starts a new map. A new
    # monocular segment has its own scale and often a poor start (benchmarks/RESULTS.md, round 8:
    # 7-Scenes mono with 70-100 frames left out, 7 gaps); 30 frames (1 s at 30 Hz) of relocalization first.
    max_lost_frames_mono: int = param(30, "the same for monocular (0: max_lost_frames)", bounds="[0, 1000000]")
    imu_only_max_s: float = param(1.0, "inertial sensors, IMU initialized: a frame that cannot be tracked visually takes the IMU prediction as its pose while the last tracked frame is at most this many seconds back (0: never)", bounds="[0, 1000]")
    max_frames_to_place: int = param(30, "continuing a loaded map (vslam run --map): frames tried for a global relocalization in it before a new map segment starts (0: none, a new segment at once)", bounds="[0, 1000000]")
    enough_matches_factor: int = param(3, "guided matching with this many times min_inliers matches needs no wider search", bounds="[0, 1000]")
    second_pass_keep_ratio: float = param(0.8, "the pose after the second guided matching is kept with at least this ratio of the first pose's inliers", bounds="[0, 1]")
    prediction_min_inlier_ratio: float = param(0.6, "a pose refined from the prediction is kept with max(min_inliers, this ratio of its matches) inliers", bounds="[0, 1]")
    refine_rounds: int = param(3, "rounds of the robust pose-only refinement (chi-square outliers dropped between rounds)", bounds="[0, 100]")
    refine_rounds_prediction: int = param(2, "the same when only refining the pose from the motion prediction", bounds="[0, 100]")
    pnp_refine_rounds: int = param(2, "refinement rounds inside PnP RANSAC", bounds="[0, 100]")
    # with depth, a first-pass pose only places the second association pass (gate 4.5 px), which a refinement
    # with the depth residuals follows: one LM round on its inliers is enough there (monocular KITTI 07
    # odometry drifts more with it: 1.16 vs < 1 m)
    pnp_refine_rounds_first_pass: int = param(1, "stereo/RGB-D: refinement rounds inside the first pass's PnP RANSAC", bounds="[0, 100]")
    align_iterations: int = param(100, "3D-3D RANSAC iterations", bounds="[1, 100000]")
    align_refine_iterations: int = param(30, "3D-3D RANSAC iterations when only refining a pose", bounds="[1, 100000]")
    align_stereo_disparity_px: float = param(2.0, "stereo 3D-3D threshold is at least the depth error of this disparity error, pixels", bounds="[0, 1000]")


@dataclass(frozen=True)
class MatchingConfig:
    """Descriptor association of the frame's keypoints with the local map (``association=match``)."""

    search_radius_px: float = param(12.0, "guided matching radius around a point's predicted projection, pixels", bounds="(0, 10000]")
    search_radius_lost_px: float = param(30.0, "wider guided matching radius when few matches were found, pixels", bounds="(0, 10000]")
    max_descriptor_distance: float = param(64.0, "Hamming bound of a match (ORB); float descriptors use the ratio only", bounds="[0, 1000000]")
    match_ratio: float = param(0.9, "best / second-best descriptor distance ratio in guided matching", bounds="(0, 1]")
    brute_force_ratio: float = param(0.8, "ratio test of the brute-force matching to the whole local map (no pose prior)", bounds="(0, 1]")
    refine_radius_min_px: float = param(4.0, "second guided matching after the pose: radius max(this, refine_radius_factor * tracking.pnp_reproj_px)", bounds="[0, 10000]")
    refine_radius_factor: float = param(1.5, "second guided matching radius in units of tracking.pnp_reproj_px", bounds="[0, 1000]")


@dataclass(frozen=True)
class KLTTrackingConfig:
    """Optical-flow association (``association=track``)."""

    min_tracks: int = param(300, "re-detect features when fewer KLT tracks survive", bounds="[0, 1000000]")
    max_tracks: int = param(1000, "re-detection tops the tracks up to this many", bounds="[1, 1000000]")
    window: int = param(15, "KLT window side in pixels", bounds="[3, 101]")
    levels: int = param(3, "KLT pyramid levels above the base image", bounds="[0, 16]")
    retry_ratio: float = param(0.5, "when fewer than this ratio of the tracks survive a predicted flow, track again from zero flow", bounds="[0, 1]")
    min_mapped_ratio: float = param(0.5, "force a keyframe when fewer than this ratio of min_tracks tracks have a map point", bounds="[0, 1]")
    mask_min_radius_px: int = param(8, "re-detection keeps at least this distance from existing tracks, pixels (or half a feature cell)", bounds="[0, 10000]")


@dataclass(frozen=True)
class TwoViewConfig:
    """Frame-to-frame essential-matrix motion (``motion=2d2d``)."""

    depth_scale_only: bool = param(False, "with depth: keep the essential matrix's translation direction, take only its scale from depth")
    min_parallax_deg: float = param(1.0, "monocular: below this parallax the reference frame is kept (translation unobservable)", bounds="[0, 180]")
    match_ratio: float = param(0.8, "ratio test of the frame-to-reference descriptor matching", bounds="(0, 1]")
    advance_ratio: float = param(0.5, "the reference frame advances when fewer than this ratio of its keypoints are matched", bounds="[0, 1]")
    advance_min_inliers_factor: int = param(4, "... or fewer than this many times tracking.min_inliers", bounds="[0, 1000]")
    max_reproj_px: float = param(2.0, "monocular: triangulated points (relative scale) need reprojection errors below this, pixels", bounds="(0, 1000]")
    min_point_parallax_deg: float = param(0.2, "monocular: triangulated points (relative scale) need this parallax, degrees", bounds="[0, 180]")
    scale_min_points: int = param(8, "monocular: points common with the last pair needed to carry the scale over", bounds="[1, 1000000]")


@dataclass(frozen=True)
class KeyframesConfig:
    """When a frame becomes a keyframe (ORB-SLAM style: track quality and time based)."""

    max_frames: int = param(20, "insert a keyframe at least every this many frames", bounds="[1, 1000000]")
    min_frames: int = param(0, "never insert a keyframe sooner than this many frames after the last one", bounds="[0, 1000000]")
    tracked_ratio: float = param(0.75, "insert when fewer than this ratio of the reference keyframe's points are tracked", bounds="[0, 1]")
    # ORB-SLAM's thRefRatio. 0.8 gives more keyframes in turns and KITTI 07 mono with local BA Sim(3) ATE
    # 0.340 -> 0.293 (07 from frames 20/40/80 0.228/0.182/0.206 -> 0.212/0.176/0.198, KITTI 06 0.034 -> 0.035),
    # but odometry alone (no backend) 07 0.343 -> 1.60 and the synthetic monocular loop-closing test's
    # correction falls short (error /3.8 instead of /5): kept at 0.7.
    tracked_ratio_mono: float = param(0.7, "the same tracked-points ratio for monocular", bounds="[0, 1]")
    # issue #28: once the IMU is initialized its prediction bridges the motion between keyframes (ORB-SLAM3
    # has its own keyframe rule for the inertial modes). Off by default (measured, stereo-inertial, EuRoC MH_01
    # 80 frames; keyframes / SE(3) ATE m with features.subpixel=off | parabola; plain stereo 33 / 0.00317 |
    # 32 / 0.00297): 0.75 (= tracked_ratio) 33 / 0.00288 | 31 / 0.00300; 0.72 29 / 0.00286 | 27 / 0.00336;
    # 0.70 28 / 0.00294 | 29 / 0.00311; 0.68 27 / 0.00278 | 27 / 0.00304; 0.65 26 / 0.00298 | 26 / 0.00312;
    # 0.62 24 / 0.00295 | 25 / 0.00319; 0.60 24 / 0.00295 | 24 / 0.00333; 0.55 20 / 0.00330 | 21 / 0.00317.
    # The ATE moves by +-0.3 mm with which frames become keyframes, not monotonic in the ratio; only 0.68 stays
    # within 0.1 mm of plain stereo under both, and with it localizing in the 50-frame map of
    # tests/test_continue_inertial.py went 0.0031 -> 0.0114 m (18 keyframes instead of 20; 0.65: 0.0041,
    # 0.72: 0.0027). About 1.1x frames/s on stereo-inertial at 0.68 (fewer local BAs, 27 vs 33 keyframes).
    tracked_ratio_inertial: float = param(0.0, "the same tracked-points ratio for stereo / RGB-D once the IMU is initialized (0: tracked_ratio)", bounds="[0, 1]")
    translation_m: float = param(0.0, "insert when moved farther than this from the reference keyframe, metres (0: off)", bounds="[0, 1000000]")
    # issue #18 item 5 (a map that grows with the place): ORB-SLAM's reference keyframe is the one
    # sharing most points with the frame; here it switches only to an *old* keyframe (a revisit), so
    # single-pass runs keep the newest keyframe as their reference.
    # 10 rather than 20: the 10-lap loop adds 2 keyframes in lap 2 instead of 6 (51, 2, 2, 0, 1, 1, 2,
    # 0, 1, 1); every benchmark row stays bit-identical (benchmarks/RESULTS.md, lifelong section).
    revisit_min_age: int = param(10, "revisit: when a keyframe this many keyframes older than the newest shares the most points with the frame, it becomes the reference (local map centre) and max_frames stops forcing keyframes (0: off)", bounds="[0, 1000000]")
    revisit_floor_mono: bool = param(True, "monocular: a revisit's new reference restarts the tracked-points count no lower than the highest count since the last keyframe (a slow loss of tracked points across reference switches then still makes a keyframe)")
    # ORB-SLAM's bNeedToInsertClose rule (100 / 70)
    close_tracked_min: int = param(100, "stereo/RGB-D: insert when fewer close (with depth) points are tracked ...", bounds="[0, 1000000]")
    close_untracked_min: int = param(70, "... and more than this many close keypoints could create new points", bounds="[0, 1000000]")


@dataclass(frozen=True)
class LocalMapConfig:
    """The local map the frame is tracked against, and the points keyframes create."""

    keyframes: int = param(8, "covisible keyframes whose points form the local map", bounds="[1, 10000]")
    keyframes_mono: int = param(24, "the same for monocular (0: keyframes)", bounds="[0, 10000]")
    max_points_per_keyframe: int = param(1000, "new points created per keyframe (depth sensors)", bounds="[0, 1000000]")
    cull_min_found_ratio: float = param(0.25, "cull points found in fewer than this ratio of the frames they were visible in", bounds="[0, 1]")
    max_map_points: int = param(200_000, "beyond this, the oldest points outside the local window are dropped (flat memory)", bounds="[1, 100000000]")


@dataclass(frozen=True)
class MonoInitConfig:
    """Monocular map initialization from two views."""

    min_matches: int = param(80, "matches to the reference frame needed to try an initialization", bounds="[1, 1000000]")
    min_parallax_deg: float = param(1.0, "the 50th largest point parallax must exceed this (ORB-SLAM), degrees", bounds="[0, 180]")
    rotation_parallax_deg: float = param(0.3, "median rotation-compensated parallax below this is pure rotation (never initializes)", bounds="[0, 180]")
    max_frames: int = param(30, "restart the reference frame after this many frames without success", bounds="[1, 1000000]")
    match_ratio: float = param(0.9, "ratio test of the matching to the reference frame", bounds="(0, 1]")
    max_descriptor_distance: float = param(64.0, "Hamming bound of the matching to the reference frame (ORB)", bounds="[0, 1000000]")
    min_depth_points: int = param(50, "stereo/RGB-D: a map starts on a frame with max(2 * tracking.min_inliers, this) points with depth", bounds="[1, 1000000]")
    essential_threshold_factor: float = param(2.0, "essential-matrix RANSAC threshold of the two-view initialization, times tracking.essential_px", bounds="(0, 1000]")
    min_inlier_fraction: float = param(0.6, "essential-matrix inliers needed, fraction of min_matches", bounds="[0, 1]")
    reproj_threshold_factor: float = param(4.0, "triangulated points must reproject within this many times tracking.essential_px in both views", bounds="(0, 1000]")
    min_point_parallax_deg: float = param(0.2, "triangulated points need more ray parallax than this, degrees", bounds="[0, 180]")
    min_point_fraction: float = param(0.5, "good triangulated points needed, fraction of min_matches", bounds="[0, 1]")
    parallax_rank: int = param(50, "the parallax of the point of this rank (largest first; ORB-SLAM: 50) is tested against min_parallax_deg", bounds="[1, 1000000]")


@dataclass(frozen=True)
class MonoMappingConfig:
    """Monocular triangulation of new points at keyframes."""

    # 1.15 deg is ORB-SLAM2's cos-parallax < 0.9998. With 0.5 deg the low-parallax points made in turns came
    # out too far for their keyframes' baseline (KITTI 07 second turn, pairs at 0.7-1.0 deg median parallax,
    # frames 140-150: depth/true 1.3-1.6 x the baseline's scale error) and PnP on them scaled the motion up.
    # The scale jump through the first turn (estimated/true step 1.00 -> 1.25, frames 25-45) is not from this
    # and remains. Sim(3) ATE with local BA, 0.5 -> 1.15 deg: KITTI 07 (160 frames) 0.385 -> 0.340, 07 from
    # frames 20/40/80: 0.236/0.200/0.249 -> 0.228/0.182/0.206, KITTI 06 0.039 -> 0.034. Without a backend
    # (odometry alone) the fewer, unrefined points drift worse: 07 0.276 -> 0.343.
    min_parallax_deg: float = param(1.15, "new points need at least this parallax between their two keyframes, degrees", bounds="[0, 180]")
    triangulation_keyframes: int = param(3, "a new keyframe triangulates with this many previous ones", bounds="[1, 1000]")
    match_ratio: float = param(0.8, "ratio test of the keypoint matching between keyframes", bounds="(0, 1]")
    max_reproj_sigmas: float = param(2.45, "new points need reprojection errors below this many octave sigmas (sqrt of chi2 5.991)", bounds="(0, 1000]")


@dataclass(frozen=True)
class DenseConfig:
    """RGB-D dense alignment (point-to-plane ICP + photometric) that refines or bridges feature poses."""

    icp_fallback: bool = param(True, "a frame with no feature pose is aligned by depth ICP to the last tracked one before it counts as lost")
    icp_photometric: bool = param(True, "the depth ICP fallback also aligns the grey images (dense RGB-D odometry)")
    # the refinement is kept when the depths agree at least as well (Tracker._refine_with_depth)
    refine: bool = param(True, "a feature pose on few inliers is refined by dense alignment to the last tracked frame")
    refine_max_inliers: int = param(150, "feature poses on fewer inliers than this are refined densely", bounds="[1, 1000000]")
    refine_downsample: int = param(2, "dense alignment runs on images reduced this many times (1: full resolution)", bounds="[1, 64]")
    links: bool = param(True, "keyframes posed by dense alignment keep that relative pose in local BA (vslam.backend.dense_links)")
    max_depth: float = param(6.0, "metres; dense alignment and dense links use depths up to min(depth.max_depth, this)", bounds="(0, 1000000]")
    doubtful_agreement: float = param(0.9, "a feature pose whose depths agree less than this is also refined from the prediction and from no motion", bounds="[0, 1]")
    min_agreement: float = param(0.6, "a dense alignment is refused when less of the aligned depths agree (depth_icp.depth_agreement)", bounds="[0, 1]")
    agreement_tolerance_m: float = param(0.02, "depths agree within this times max(1, z^2), metres (Kinect noise, Khoshelham & Elberink 2012)", bounds="(0, 1000]")
    agreement_step: int = param(8, "depth agreement is measured on every this-many-th pixel (rows and columns)", bounds="[1, 1024]")
    max_step_deg: float = param(30.0, "a dense alignment rotating more than this is refused, degrees", bounds="[0, 180]")
    max_step_m: float = param(0.5, "a dense alignment moving more than this is refused, metres", bounds="[0, 1000000]")
    icp_max_depth_diff: float = param(0.07, "OpenCV ICP odometry: correspondences differ in depth by at most this, metres", bounds="(0, 1000]")
    icp_max_points_part: float = param(0.35, "OpenCV ICP odometry: at most this fraction of the pixels is used", bounds="(0, 1]")
    icp_iterations: tuple[int, ...] = param((7, 7, 7, 10), "OpenCV ICP odometry: iterations per pyramid level (finest first)", bounds="[1, 1000]")


@dataclass(frozen=True)
class FrontendConfig:
    """Frontend settings."""

    association: str = param("match", "match (descriptors, guided by projecting the local map) or track (KLT optical flow)")
    motion: str = param("3d2d", "3d2d (PnP against the local map), 3d3d (3D-3D alignment; stereo/RGB-D) or 2d2d (essential matrix)")
    depth: DepthConfig = section(DepthConfig, "depth and stereo measurements", ("",))
    tracking: TrackingConfig = section(TrackingConfig, "pose estimation and loss", ("",))
    matching: MatchingConfig = section(MatchingConfig, "descriptor association with the local map", ("",))
    klt: KLTTrackingConfig = section(KLTTrackingConfig, "KLT optical-flow association", ("klt_",))
    two_view: TwoViewConfig = section(TwoViewConfig, "essential-matrix (2d2d) motion", ("two_view_",))
    keyframes: KeyframesConfig = section(KeyframesConfig, "keyframe decision", ("kf_",))
    local_map: LocalMapConfig = section(LocalMapConfig, "local map and point creation", ("local_", ""))
    init: MonoInitConfig = section(MonoInitConfig, "monocular initialization", ("init_",))
    mono: MonoMappingConfig = section(MonoMappingConfig, "monocular point triangulation", ("mono_",))
    dense: DenseConfig = section(DenseConfig, "RGB-D dense alignment", ("depth_", "dense_"))

    def __post_init__(self) -> None:
        if self.association not in ASSOCIATIONS:
            raise ConfigError(f"frontend.association must be one of {ASSOCIATIONS}, got {self.association!r}")
        if self.motion not in MOTIONS:
            raise ConfigError(f"frontend.motion must be one of {MOTIONS}, got {self.motion!r}")
        if self.tracking.min_inliers < 6:
            raise ConfigError(f"frontend.tracking.min_inliers must be >= 6, got {self.tracking.min_inliers}")
        if self.dense.refine_downsample < 1:
            raise ConfigError(f"frontend.dense.refine_downsample must be >= 1 (1 = full resolution), got {self.dense.refine_downsample}")
        if self.depth.stereo_flow not in STEREO_FLOWS:
            raise ConfigError(f"frontend.depth.stereo_flow must be one of {STEREO_FLOWS}, got {self.depth.stereo_flow!r}")
        if not 0 <= self.depth.min_depth < self.depth.max_depth:
            raise ConfigError(f"frontend.depth.min_depth ({self.depth.min_depth}) must be >= 0 and below "
                              f"frontend.depth.max_depth ({self.depth.max_depth}), metres")

    def check_sensor(self, sensor: str) -> None:
        """Raise :class:`ConfigError` for a motion method the sensor cannot support."""
        if sensor not in SENSORS:
            raise ConfigError(f"sensor must be one of {SENSORS}, got {sensor!r}")
        if sensor == "mono" and self.motion == "3d3d":
            raise ConfigError("frontend.motion=3d3d needs per-frame 3D points: use sensor stereo/rgbd, or motion 3d2d/2d2d")
