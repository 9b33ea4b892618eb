"""Configuration of the optimization backend: one frozen dataclass per solver.

Defaults follow ORB-SLAM2 (Mur-Artal & Tardos, T-RO 2017, Sec. VI): local BA runs a few robust
Levenberg-Marquardt iterations, drops the observations whose chi-square error exceeds the 95 %
quantile (5.991 for 2 dof monocular, 7.815 for 3 dof stereo), then refines without the kernel.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

from vslam.errors import ConfigError
from vslam.geometry.camera import RGBD_VIRTUAL_BASELINE
from vslam.map.config import PoseGraphConfig  # shared with loop closing; re-exported here
from vslam.param import param, section

_SOLVERS = ("schur", "gtsam")


@dataclass(frozen=True)
class LocalBAConfig:
    """Windowed (local) bundle adjustment."""

    window_size: int = param(10, "most recent keyframes optimized (the caller builds the window)", bounds="[1, 10000]")
    # ORB-SLAM: 5; 3 give the same accuracy and outlier recall on the synthetic sweep here, 20 % faster
    iterations_robust: int = param(3, "LM iterations of the first pass with the Huber kernel (0: no robust pass, no outlier removal)", bounds="[0, 1000]")
    iterations_refine: int = param(10, "LM iterations after removing chi-square outliers, no kernel (ORB-SLAM: 10)", bounds="[0, 1000]")
    huber_mono: float = param(math.sqrt(5.991), "Huber threshold on the whitened error sqrt(chi2), 2-dof observations", bounds="(0, 1000]")
    huber_stereo: float = param(math.sqrt(7.815), "Huber threshold on the whitened error sqrt(chi2), 3-dof observations", bounds="(0, 1000]")
    chi2_mono: float = param(5.991, "chi-square inlier threshold, 2-dof observations (95 %)", bounds="(0, 1000000]")
    chi2_stereo: float = param(7.815, "chi-square inlier threshold, 3-dof observations (95 %)", bounds="(0, 1000000]")
    # the tracker's and loop closer's
    rgbd_virtual_baseline: float = param(RGBD_VIRTUAL_BASELINE, "metres; RGB-D depth z becomes a virtual right coordinate u - fx b / z (ORB-SLAM2)", bounds="(0, 100]")
    # u_right: u_r - (u - fx b / z) with errors independent of u's (ORB-SLAM2's stereo edge), i.e. a disparity
    # error of variance 2 sigma^2 correlated with u's error (+1/sqrt 2). disparity: (u - u_r) - fx b / z,
    # independent of u, same sigma: the model of a depth sensor (its depth does not move with the keypoint's
    # location error), so u's information is not counted twice. RGB-D, the local BA of the second keyframe of
    # the synthetic RGB-D sequence (exact ground truth, test_local_mapping): u_right moved it from 7.3 mm error
    # (odometry) to 24.2 mm (Mahalanobis^2 67 under the problem's own covariance, i.e. a modelling error),
    # disparity to 6.2 mm; synthetic ATE (9 / 15 / 60 frames, odometry 2.82 / 3.47 / 18.0 mm) 6.70 / 4.93 /
    # 4.79 -> 2.42 / 2.82 / 4.04 mm. Stereo: KITTI 06 (the right column comes from patch matching, so
    # disparity would be the physical model) local BA 0.0557 -> 0.066 m with disparity, 0.062 with
    # sigma_d = sqrt 2 sigma: the stereo default stays u_right.
    # RGB-D default (issue 5): disparity with disparity_sigma_scale = sqrt 2, the depth weight of u_right (whose
    # marginal disparity std is sqrt 2 sigma) without its double-counted u. ATE m, u_right -> default, loop
    # off: fr1/desk 9 0.00463 -> 0.00420 (odometry 0.00447: only this model makes BA help there); cabinet
    # 0.0280 -> 0.0268; 7-Scenes 0.0471 -> 0.0476 (0.0470 at 975f2d3). With loop closing (the default
    # pipeline): cabinet 0.0357 -> 0.0322 (the loop's RANSAC pose refined on reprojection, no global BA after a
    # weak loop: see ClosingConfig.refine_ransac_pose / global_ba_weak_loops; u_right with those 0.0259);
    # 7-Scenes 0.0425 -> 0.0440 (0.0433 at 975f2d3). Scale 1 (disparity std sigma) trusts depth more: fr1
    # 0.00419, cabinet 0.0245, 7-Scenes 0.0501 (> 0.05).
    rgbd_residual: str = param("disparity", "third residual of an RGB-D observation: u_right (ORB-SLAM2's stereo edge) or disparity")
    stereo_residual: str = param("u_right", "third residual of a stereo observation: u_right or disparity")
    # A depth sensor's disparity noise is far below a pixel (Kinect sigma_z ~ 1.4e-3 z^2 m is ~0.06 px of
    # virtual disparity), so < 1 trusts depth more. Measured (disparity residual, loop off) for 1.41 / 1 / 0.7 /
    # 0.5 / 0.35 / 0.25: fr1 4.20 / 4.19 / 4.14 / 4.09 / 4.06 / 4.02 mm; cabinet 26.8 / 24.5 / 29.2 / 24.9 /
    # 32.4 / 31.3 mm (with loop, 0.5: 34.8); 7-Scenes first 350 frames 23.9 / 23.4 / 23.4 / 22.6 / 22.9 / 23.4
    # mm (u_right 23.1); full 7-Scenes 0.5: 0.0518 m (30-frame relative error 0.0325). Synthetic 10 keyframes
    # x 3000 points (benchmarks/backend_bench.py problem): free-pose error u_right 8.09, disparity 6.57, 0.5:
    # 5.59 mm.
    disparity_sigma_scale: float = param(math.sqrt(2.0), "std of the disparity residual in units of the keypoint's sigma (disparity residuals only)", bounds="(0, 1000]")
    # issue #24: a depth sensor's depth error grows with z^2 (Kinect sigma_z ~ 1.4e-3 z^2 m, Khoshelham & Elberink
    # 2012), i.e. its disparity fx b / z has a constant error, independent of the keypoint's octave; this sigma
    # replaces disparity_sigma_scale * sigma_octave for RGB-D disparity residuals. -1 (auto): the dataset's
    # figure (vslam.datasets.base.RGBD_DISPARITY_SIGMA_PX, 0.1 px), off where its depth is not registered to
    # its colour camera (7-Scenes: trusting it made that row worse at every value, benchmarks/RESULTS.md, issue
    # #24 item 3); resolved by vslam.api.run_path (vslam.config.with_depth_noise); a System built directly
    # with -1 keeps it off.
    rgbd_disparity_sigma_px: float = param(-1.0, "RGB-D disparity residuals: a constant disparity std in pixels (the z^2 depth-noise law), whatever the keypoint's octave (0: off, disparity_sigma_scale times its sigma; -1: auto, the dataset's figure for its depth sensor: 0.1, or off where the depth is not registered to the colour camera, as in 7-Scenes)", bounds="[-1, 1000]")
    solver: str = param("schur", "schur (vectorized NumPy/SciPy LM on the reduced camera system) or gtsam (the reference)")
    lambda_initial: float = param(1e-4, "initial LM damping (Marquardt scaling of the Hessian diagonal)", bounds="(0, 1e10]")
    relative_tolerance: float = param(1e-4, "stop a pass when an iteration's relative cost decrease falls below this", bounds="[0, 1]")
    min_depth: float = param(1e-3, "metres; an observation whose point is closer (or behind) is an outlier", bounds="[0, 1000]")
    # issue #26 (vslam.backend.schur_sparse): the dense S costs O(n^3) per LM step, the block-sparse one follows the
    # covisibility graph. Measured (CPU per damped solve, synthetic trajectory, 3-9 % of the blocks non-zero): 99
    # cameras 5.2 vs 2.6 ms, 199: 27.6 vs 7.1, 399: 150 vs 15. Below 200 the gain is < 25 ms a step, and 200 keeps
    # every local BA and the pinned runs' global BAs (7-Scenes loop: 157 keyframes) on the dense path, bit for bit.
    sparse_min_cameras: int = param(200, "solve the reduced camera system block-sparse (SuperLU) above this many variable keyframes; dense Cholesky at or below (0: always sparse)", bounds="[0, 1000000000]")

    def __post_init__(self) -> None:
        if self.solver not in _SOLVERS:
            raise ConfigError(f"backend solver must be one of {_SOLVERS}, got {self.solver!r}")
        for name in ("rgbd_residual", "stereo_residual"):
            if getattr(self, name) not in ("u_right", "disparity"):
                raise ConfigError(f"backend {name} must be 'u_right' or 'disparity', got {getattr(self, name)!r}")
        if self.iterations_robust < 0 or self.iterations_refine < 0 or self.iterations_robust + self.iterations_refine == 0:
            raise ConfigError(
                f"BA needs at least one iteration, got iterations_robust={self.iterations_robust}, "
                f"iterations_refine={self.iterations_refine}"
            )
        if self.window_size < 2:
            raise ConfigError(f"local BA window_size must be >= 2, got {self.window_size}")
        if self.rgbd_disparity_sigma_px < 0 and self.rgbd_disparity_sigma_px != -1.0:
            raise ConfigError(f"backend rgbd_disparity_sigma_px must be >= 0 (or -1: auto), got {self.rgbd_disparity_sigma_px}")
        for name in ("huber_mono", "huber_stereo", "chi2_mono", "chi2_stereo", "rgbd_virtual_baseline", "lambda_initial",
                     "disparity_sigma_scale"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"backend config {name} must be > 0, got {getattr(self, name)}")


@dataclass(frozen=True)
class GlobalBAConfig(LocalBAConfig):
    """Full bundle adjustment over every keyframe (first keyframe fixed); more iterations."""

    iterations_robust: int = param(10, "LM iterations of the first pass with the Huber kernel (0: no robust pass, no outlier removal)", bounds="[0, 1000]")
    iterations_refine: int = param(20, "LM iterations after removing chi-square outliers, no kernel", bounds="[0, 1000]")
    # issue #26 round 10 (benchmarks/RESULTS.md): the sessions of a `vslam map` component arrive optimized
    # (their own local BAs, the seams' local BAs, the pose graph). At relative_tolerance 1e-4 the global BA
    # of the 16-arc synthetic fleet takes 12 iterations (1.12 s) to reach the RMS (0.6797 px) and ATE
    # (0.00428 m) that 1e-3 reaches in 5 (0.45 s); 7-Scenes in 5 sessions: 7 -> 6 iterations, ATE 0.0465 m
    # both. Loop closing's global BA keeps relative_tolerance.
    merged_relative_tolerance: float = param(1e-3, "relative_tolerance of the global BA that ends `vslam map` (a component merged from optimized sessions)", bounds="[0, 1]")


@dataclass(frozen=True)
class EKFConfig:
    """Constant-velocity pose EKF (see :mod:`vslam.backend.ekf`)."""

    accel_sigma: float = param(1.0, "m/s^2 per sqrt(s); white linear-acceleration noise density driving the velocity", bounds="(0, 1000000]")
    angular_accel_sigma: float = param(1.0, "rad/s^2 per sqrt(s); white angular-acceleration noise density", bounds="(0, 1000000]")
    initial_sigma_position: float = param(1e-3, "metres; std of the first state's position", bounds="(0, 1000000]")
    initial_sigma_rotation: float = param(1e-3, "radians; std of the first state's rotation", bounds="(0, 1000000]")
    initial_sigma_velocity: float = param(1.0, "m/s; std of the unknown initial velocity", bounds="(0, 1000000]")
    initial_sigma_angular_velocity: float = param(1.0, "rad/s; std of the unknown initial angular velocity", bounds="(0, 1000000]")
    default_sigma_position: float = param(0.01, "metres; measurement std when update gets none", bounds="(0, 1000000]")
    default_sigma_rotation: float = param(0.01, "radians; measurement std when update gets none", bounds="(0, 1000000]")
    gate_chi2: float = param(float("inf"), "Mahalanobis gate on the 6-dof innovation (inf disables; 22.46 = 99.9 %)", bounds="(0, inf]")
    inlier_error_px: float = param(1.0, "pixels; assumed error of the frontend's inliers, scales the measured pose's covariance", bounds="(0, 10000]")
    min_inlier_error_px: float = param(0.1, "pixels; floor of that error (keeps the covariance of a perfect fit positive)", bounds="(0, 10000]")

    def __post_init__(self) -> None:
        for name in (
            "accel_sigma", "angular_accel_sigma", "initial_sigma_position", "initial_sigma_rotation",
            "initial_sigma_velocity", "initial_sigma_angular_velocity", "default_sigma_position",
            "default_sigma_rotation", "gate_chi2", "inlier_error_px", "min_inlier_error_px",
        ):
            if not getattr(self, name) > 0:
                raise ConfigError(f"EKF config {name} must be > 0, got {getattr(self, name)}")


@dataclass(frozen=True)
class FusionConfig:
    """Point fusion before each local BA: the window's points and the new keyframe's (ORB-SLAM2 SearchInNeighbors)."""

    enabled: bool = param(True, "before each local BA, fuse the window's points and the new keyframe's (needs association=match)")
    radius_px: float = param(4.0, "point fusion search radius in pixels", bounds="(0, 10000]")
    max_descriptor_distance: float = param(50.0, "point fusion descriptor threshold (Hamming)", bounds="[0, 1000000]")
    ratio: float = param(1.0, "point fusion ratio test (1.0: off, the closest descriptor in the radius wins)", bounds="(0, 1]")
    # Off: on KITTI 07 (mono, Sim(3) ATE, local BA) fusion raised the ATE on all 5 clips measured (160 frames
    # 0.431 vs 0.376 m; also with the octave check of ORB-SLAM2's Fuse, or with only its merges or only its
    # new observations).
    mono: bool = param(False, "fuse monocular maps too")


@dataclass(frozen=True)
class MonoBAConfig:
    """Which points a monocular local BA optimizes, and what happens to the ones it leaves out."""

    # 3: no two-view points; their depth drifts ~1 % outwards per local BA, which new keyframes' PnP turns into
    # scale drift.
    min_observations: int = param(3, "monocular BA leaves out points seen by fewer keyframes (2 keeps every point)", bounds="[1, 1000]")
    min_multiview_points: int = param(100, "min_observations is skipped while fewer points would remain", bounds="[0, 1000000]")
    # Measured on KITTI 07 mono, 160 frames (Sim(3) ATE / RPE trans, m; odometry alone 0.276 / 0.029): keep
    # 0.290 / 0.073 (the left-out points stay where tracking put them, so the frames between keyframes
    # saw-tooth against the corrected keyframes: RPE x2.5), transport 0.397 / 0.036, retriangulate 0.385 /
    # 0.034 (before the retriangulation gate below; with it, the full pipeline gives 0.326). Over 5 clips (07 from frames 0, 20, 40, 80 and 06 mono) keep averages 0.192, retriangulate 0.222,
    # odometry 0.252. The default is retriangulate: a map consistent with its keyframes (smooth trajectory)
    # over the lower ATE that keep gets on KITTI 07.
    left_out: Literal["keep", "transport", "retriangulate"] = param("retriangulate", "two-view points left out of a monocular BA: keep, transport (with their keyframe) or retriangulate")
    # Without this gate (cheirality alone) a low-parallax point lands anywhere on its ray: 7-Scenes mono's second
    # segment drifted 2.6x in scale (docs/architecture.md). 2 px: KITTI 07 0.348, 4 px: 0.326.
    retriangulate_max_reproj_px: float = param(4.0, "a re-triangulated point moves only if it reprojects within this many pixels in both keyframes", bounds="(0, 1000]")
    retriangulate_min_parallax_deg: float = param(1.0, "... and is seen with at least this parallax, degrees (else it keeps its position)", bounds="[0, 180]")
    # issue #24 candidate (0 = off while measured): ORB-SLAM's local BA takes every covisible keyframe, so its
    # monocular window is wider than the stereo/RGB-D one here. Measured with local.window_size=15 (the same
    # monocular runs): one 7-Scenes mono start of five fails (0.348 m), benchmarks/RESULTS.md (issue #24).
    window_size: int = param(0, "monocular local BA: the most recent keyframes optimized (0: local.window_size)", bounds="[0, 10000]")

    def __post_init__(self) -> None:
        if self.min_observations < 2:
            raise ConfigError(f"backend mono.min_observations must be >= 2 (a monocular point needs two views), "
                              f"got {self.min_observations}")


@dataclass(frozen=True)
class CullingConfig:
    """Culling after each keyframe: new points too few keyframes observe (ORB-SLAM MapPointCulling), and
    optionally redundant keyframes (KeyFrameCulling)."""

    min_observations: int = param(2, "a point born two keyframes ago that fewer keyframes observe is culled (0 or 1 disables)", bounds="[0, 1000]")
    age_keyframes: int = param(3, "a new point is judged by min_observations once its segment has this many keyframes from its own on (ORB-SLAM: 3)", bounds="[0, 1000000]")
    keyframes: bool = param(False, "flag redundant keyframes bad (ORB-SLAM KeyFrameCulling)")
    redundant_ratio: float = param(0.9, "fraction of a keyframe's points seen by >= redundant_min_observers others that makes it redundant", bounds="[0, 1]")
    redundant_min_observers: int = param(3, "other keyframes that must see a point for it to count as redundant (ORB-SLAM: 3)", bounds="[1, 1000]")
    keep_recent_keyframes: int = param(3, "the newest this many keyframes of a segment are never culled", bounds="[0, 1000000]")


@dataclass(frozen=True)
class BackendConfig:
    """Which backend runs and how."""

    type: Literal["graph", "ekf"] = param("graph", "graph (windowed BA + pose graph / global BA) or ekf (constant-velocity Kalman filter)")
    local_ba: bool = param(True, "run windowed BA after each keyframe (graph backend)")
    mode: Literal["deterministic", "parallel", "realtime"] = param("deterministic", "deterministic (local mapping inline, same result every run), parallel (local BA solved in a worker thread, applied at a fixed frame lag: same result every run) or realtime (background worker)")
    parallel_worker: Literal["thread", "process"] = param("process", "parallel mode: the local BA solve runs in a child process (no GIL shared with tracking) or a thread")
    lag_frames: int = param(8, "parallel mode: a keyframe's local BA is applied this many frames after its keyframe, or at the end of the frame bringing the next keyframe when that comes first", bounds="[0, 1000000]")
    final_ba: bool = param(False, "run a full global bundle adjustment at the end of the run")
    final_inertial_ba: bool = param(True, "mono- and stereo-inertial, IMU initialized by the run: a full visual-inertial BA of the current segment at the end of the run (not after a placement in a loaded map, whose keyframes are another recording's; not RGB-D, whose local BA stays visual)")
    covisible_keyframes: int = param(10, "local BA window: the local.window_size latest keyframes plus this many strongest covisible ones", bounds="[0, 10000]")
    max_fixed_keyframes: int = param(20, "at most this many keyframes outside the window (sharing most points) are held fixed", bounds="[0, 10000]")
    stereo_far_baselines: float = param(35.0, "stereo observations of points farther than this many baselines enter BA as monocular (0: off)", bounds="(0, 1000000]")
    # ORB-SLAM2's triangulation minimum, cos 0.9998. Otherwise its depth is unobservable and LM slides it along
    # its ray, dragging the poses. EuRoC V1_01 (camera at rest): one such point went from 4.2 m to the camera
    # centre when the LM converged, moving the second keyframe 0.9 mm, and stopped the default solve 0.8 mm
    # short of that minimum (the Schur solver and GTSAM disagreed by 1.0 mm); without it both converge in 4
    # iterations to the same pose (0.5 um apart). EuRoC ATE with local BA 0.89 -> 0.88 mm.
    depthless_min_parallax_deg: float = param(1.15, "stereo/RGB-D: a point with no depth observation in BA needs this parallax, degrees (0: off)", bounds="[0, 180]")
    fusion: FusionConfig = section(FusionConfig, "point fusion before each local BA", ("fuse_",), {"fuse": "enabled"})
    mono: MonoBAConfig = section(MonoBAConfig, "which points a monocular local BA optimizes", ("mono_",))
    cull: CullingConfig = section(CullingConfig, "point and keyframe culling", ("cull_", ""))
    local: LocalBAConfig = section(LocalBAConfig, "windowed (local) bundle adjustment")
    global_ba: GlobalBAConfig = section(GlobalBAConfig, "global bundle adjustment")
    pose_graph: PoseGraphConfig = section(PoseGraphConfig, "pose-graph optimization")
    ekf: EKFConfig = section(EKFConfig, "constant-velocity pose EKF")

    # Local BA, loop closing off, ATE m, reference -> interpolate: KITTI 06 stereo 0.0561 -> 0.0557, KITTI 07
    # mono 0.340 -> 0.339, fr1/desk 9 frames 0.00468 -> 0.00463, EuRoC V1_01 40 frames 0.00089 -> 0.00088 (with
    # the u_right RGB-D residual); synthetic RGB-D (exact ground truth, 60 frames) 0.0057 -> 0.0040.
    dense_link_min_depth: float = param(0.1, "metres; an RGB-D dense-link sample enters local BA only if it lies this far in front of both keyframes", bounds="[0, 1000]")
    frame_correction: Literal["reference", "interpolate"] = param("interpolate", "frames between keyframes follow them: reference (their reference keyframe) or interpolate (blend by time)")

    def __post_init__(self) -> None:
        if self.mode not in ("deterministic", "parallel", "realtime"):
            raise ConfigError(f"backend mode must be deterministic, parallel or realtime, got {self.mode!r}")
        if self.parallel_worker not in ("thread", "process"):
            raise ConfigError(f"backend parallel_worker must be thread or process, got {self.parallel_worker!r}")
        if self.lag_frames < 1:
            raise ConfigError(f"backend lag_frames must be >= 1, got {self.lag_frames}")
        if not self.dense_link_min_depth > 0:
            raise ConfigError(f"backend dense_link_min_depth must be > 0, got {self.dense_link_min_depth}")
        if self.frame_correction not in ("reference", "interpolate"):
            raise ConfigError(f"backend frame_correction must be 'reference' or 'interpolate', got {self.frame_correction!r}")
