"""Configuration of the optimization backend: one frozen dataclass per solver.

Defaults follow ORB-SLAM2 (Mur-Artal & Tardos, T-RO 2017, Sec. VI): local BA runs a few robust
Levenberg-Marquardt iterations, drops the observations whose chi-square error exceeds the 95 %
quantile (5.991 for 2 dof monocular, 7.815 for 3 dof stereo), then refines without the kernel.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

from vslam.errors import ConfigError
from vslam.geometry.camera import RGBD_VIRTUAL_BASELINE
from vslam.map.config import PoseGraphConfig  # shared with loop closing; re-exported here

_SOLVERS = ("schur", "gtsam")


@dataclass(frozen=True)
class LocalBAConfig:
    """Windowed (local) bundle adjustment.

    Attributes:
        window_size: number of most recent keyframes optimized (the caller builds the window;
            the value is carried here so the whole backend is configured in one place).
        iterations_robust: LM iterations of the first pass with the Huber kernel (ORB-SLAM: 5; 3 give
            the same accuracy and outlier recall on the synthetic sweep here, 20 % faster). 0 skips
            the robust pass and the outlier removal (plain least squares on every observation).
        iterations_refine: LM iterations after removing chi-square outliers, no kernel (ORB-SLAM: 10).
        huber_mono / huber_stereo: Huber thresholds on the whitened error ``sqrt(chi2)``.
        chi2_mono / chi2_stereo: chi-square thresholds of the inlier test (95 %, 2 and 3 dof).
        rgbd_virtual_baseline: metres; RGB-D depth ``z`` becomes a virtual right coordinate
            ``u_r = u - fx * b / z`` (ORB-SLAM2) so depth is handled by the stereo factor.
        rgbd_residual / stereo_residual: the third residual of an RGB-D / stereo observation.
            ``u_right``: ``u_r - (u - fx b / z)`` with errors independent of ``u``'s (ORB-SLAM2's
            stereo edge), i.e. a disparity error of variance ``2 sigma^2`` correlated with ``u``'s
            error (+1/sqrt 2). ``disparity``: ``(u - u_r) - fx b / z``, independent of ``u``, same
            ``sigma``: the model of a depth sensor (its depth does not move with the keypoint's
            location error), so ``u``'s information is not counted twice. RGB-D, the local BA of
            the second keyframe of the synthetic RGB-D sequence (exact ground truth, test_local_mapping):
            u_right moved it from 7.3 mm error (odometry) to 24.2 mm (Mahalanobis^2 67 under the
            problem's own covariance, i.e. a modelling error), disparity to 6.2 mm; synthetic ATE
            (9 / 15 / 60 frames, odometry 2.82 / 3.47 / 18.0 mm) 6.70 / 4.93 / 4.79 -> 2.42 / 2.82 /
            4.04 mm. Stereo: KITTI 06 (the right column comes from patch matching, so ``disparity``
            would be the physical model) local BA 0.0557 -> 0.066 m with ``disparity``, 0.062 with
            ``sigma_d = sqrt 2 sigma``: the stereo default stays ``u_right``.
            RGB-D default (issue 5): ``disparity`` with ``disparity_sigma_scale = sqrt 2``, the depth
            weight of u_right (whose marginal disparity std is ``sqrt 2 sigma``) without its
            double-counted ``u``. ATE m, u_right -> default, loop off: fr1/desk 9 0.00463 -> 0.00420
            (odometry 0.00447: only this model makes BA help there); cabinet 0.0280 -> 0.0268;
            7-Scenes 0.0471 -> 0.0476 (0.0470 at 975f2d3). With loop closing (the default pipeline):
            cabinet 0.0357 -> 0.0322 (the loop's RANSAC pose refined on reprojection, no global BA
            after a weak loop: see ``ClosingConfig.refine_ransac_pose`` / ``global_ba_weak_loops``;
            u_right with those 0.0259); 7-Scenes 0.0425 -> 0.0440 (0.0433 at 975f2d3). Scale 1 (disparity std ``sigma``) trusts depth more: fr1 0.00419, cabinet 0.0245,
            7-Scenes 0.0501 (> 0.05).
        disparity_sigma_scale: std of the disparity residual in units of the keypoint's ``sigma``
            (``disparity`` residuals only; 1 = the same as ``u``, ``v``). A depth sensor's disparity
            noise is far below a pixel (Kinect ``sigma_z ~ 1.4e-3 z^2`` m is ``~0.06`` px of virtual
            disparity), so < 1 trusts depth more. Measured (disparity residual, loop off) for 1.41 /
            1 / 0.7 / 0.5 / 0.35 / 0.25: fr1 4.20 / 4.19 / 4.14 / 4.09 / 4.06 / 4.02 mm; cabinet 26.8 /
            24.5 / 29.2 / 24.9 / 32.4 / 31.3 mm (with loop, 0.5: 34.8); 7-Scenes first 350 frames 23.9
            / 23.4 / 23.4 / 22.6 / 22.9 / 23.4 mm (u_right 23.1); full 7-Scenes 0.5: 0.0518 m
            (30-frame relative error 0.0325). Synthetic 10 keyframes x 3000 points (benchmarks/
            backend_bench.py problem): free-pose error u_right 8.09, disparity 6.57, 0.5: 5.59 mm.
        solver: ``"schur"`` (vectorized NumPy/SciPy LM on the reduced camera system, default,
            fastest here) or ``"gtsam"`` (``LevenbergMarquardtOptimizer``, the reference).
        lambda_initial: initial LM damping (Marquardt scaling of the Hessian diagonal).
        relative_tolerance: stop a pass when the relative cost decrease of an iteration falls below it.
        min_depth: metres; an observation whose point is closer (or behind) is an outlier.
    """

    window_size: int = 10
    iterations_robust: int = 3
    iterations_refine: int = 10
    huber_mono: float = math.sqrt(5.991)
    huber_stereo: float = math.sqrt(7.815)
    chi2_mono: float = 5.991
    chi2_stereo: float = 7.815
    rgbd_virtual_baseline: float = RGBD_VIRTUAL_BASELINE  # the tracker's and loop closer's
    rgbd_residual: str = "disparity"
    stereo_residual: str = "u_right"
    disparity_sigma_scale: float = math.sqrt(2.0)
    solver: str = "schur"
    lambda_initial: float = 1e-4
    relative_tolerance: float = 1e-4
    min_depth: float = 1e-3

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
        for name in ("huber_mono", "huber_stereo", "chi2_mono", "chi2_stereo", "rgbd_virtual_baseline", "lambda_initial",
                     "disparity_sigma_scale"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"backend config {name} must be > 0, got {getattr(self, name)}")


@dataclass(frozen=True)
class GlobalBAConfig(LocalBAConfig):
    """Full bundle adjustment over every keyframe (first keyframe fixed); more iterations."""

    iterations_robust: int = 10
    iterations_refine: int = 20


@dataclass(frozen=True)
class EKFConfig:
    """Constant-velocity pose EKF (see :mod:`vslam.backend.ekf`).

    Attributes:
        accel_sigma: m/s^2 per sqrt(s); white linear-acceleration noise density driving the velocity.
        angular_accel_sigma: rad/s^2 per sqrt(s); idem for the angular velocity.
        initial_sigma_position / initial_sigma_rotation: std of the first state (m, rad).
        initial_sigma_velocity / initial_sigma_angular_velocity: std of the unknown initial velocity.
        default_sigma_position / default_sigma_rotation: measurement std when ``update`` gets none.
        gate_chi2: Mahalanobis gate on the 6-dof innovation (``inf`` disables); 22.46 = 99.9 %, 6 dof.
    """

    accel_sigma: float = 1.0
    angular_accel_sigma: float = 1.0
    initial_sigma_position: float = 1e-3
    initial_sigma_rotation: float = 1e-3
    initial_sigma_velocity: float = 1.0
    initial_sigma_angular_velocity: float = 1.0
    default_sigma_position: float = 0.01
    default_sigma_rotation: float = 0.01
    gate_chi2: float = float("inf")

    def __post_init__(self) -> None:
        for name in (
            "accel_sigma", "angular_accel_sigma", "initial_sigma_position", "initial_sigma_rotation",
            "initial_sigma_velocity", "initial_sigma_angular_velocity", "default_sigma_position",
            "default_sigma_rotation", "gate_chi2",
        ):
            if not getattr(self, name) > 0:
                raise ConfigError(f"EKF config {name} must be > 0, got {getattr(self, name)}")


@dataclass(frozen=True)
class BackendConfig:
    """Which backend runs and how.

    Attributes:
        type: ``graph`` (windowed bundle adjustment + pose graph / global BA) or ``ekf`` (a
            constant-velocity extended Kalman filter over the camera pose).
        local_ba: run windowed BA after each keyframe (graph backend).
        mode: ``deterministic`` (local mapping inline: the same result every run) or ``realtime``
            (local mapping in a background worker so tracking never waits).
        final_ba: run a full global bundle adjustment at the end of the run.
        covisible_keyframes: local BA window = the ``local.window_size`` latest keyframes plus this
            many strongest covisibility neighbours of the new keyframe.
        max_fixed_keyframes: at most this many keyframes outside the window (those sharing most points
            with it) are added as constant poses (the gauge).
        cull_min_observations: a point born two keyframes ago that fewer keyframes observe is culled
            (ORB-SLAM MapPointCulling; 0 or 1 disables).
        cull_keyframes: flag redundant keyframes bad (ORB-SLAM KeyFrameCulling).
        redundant_ratio: fraction of a keyframe's points seen by >= 3 others that makes it redundant.
        stereo_far_baselines: stereo observations of points farther than this many baselines enter BA
            as monocular ones (ORB-SLAM2's close/far split at 35-40; 0 keeps every disparity).
        depthless_min_parallax_deg: stereo / RGB-D: a point with no depth or disparity observation in
            the BA problem (a far stereo point) enters it only if its viewing rays span at least this
            angle (ORB-SLAM2's triangulation minimum, cos 0.9998); otherwise its depth is unobservable
            and LM slides it along its ray, dragging the poses. EuRoC V1_01 (camera at rest): one such
            point went from 4.2 m to the camera centre when the LM converged, moving the second
            keyframe 0.9 mm, and stopped the default solve 0.8 mm short of that minimum (the Schur
            solver and GTSAM disagreed by 1.0 mm); without it both converge in 4 iterations to the same
            pose (0.5 um apart). EuRoC ATE with local BA 0.89 -> 0.88 mm. 0 keeps every point.
        fuse: before each local BA, match the window's points into the new keyframe and the new
            keyframe's points into the window (ORB-SLAM2 SearchInNeighbors): adds observations and
            merges duplicate points (needs descriptors, i.e. ``frontend.association=match``).
        fuse_radius_px / fuse_max_descriptor_distance: search radius and descriptor threshold (Hamming).
        fuse_mono: fuse monocular maps too. Off: on KITTI 07 (mono, Sim(3) ATE, local BA) fusion raised
            the ATE on all 5 clips measured (160 frames 0.431 vs 0.376 m; also with the octave check
            of ORB-SLAM2's Fuse, or with only its merges or only its new observations).
        mono_min_observations: monocular BA leaves out points seen by fewer keyframes (3: no two-view
            points; their depth drifts ~1 % outwards per local BA, which new keyframes' PnP turns into
            scale drift); 2 keeps every point. Skipped while fewer than ``mono_min_multiview_points``
            points would remain (the first windows after initialization).
        mono_left_out: what happens to the two-view points left out of a monocular BA when the
            keyframes move: ``keep`` (stay put), ``transport`` (move with their reference keyframe's
            correction) or ``retriangulate`` (triangulate again with the corrected poses).
            Measured on KITTI 07 mono, 160 frames (Sim(3) ATE / RPE trans, m; odometry alone 0.276 /
            0.029): keep 0.290 / 0.073 (the left-out points stay where tracking put them, so the
            frames between keyframes saw-tooth against the corrected keyframes: RPE x2.5),
            transport 0.397 / 0.036, retriangulate 0.385 / 0.034. Over 5 clips (07 from frames 0, 20,
            40, 80 and 06 mono) keep averages 0.192, retriangulate 0.222, odometry 0.252. The default
            is ``retriangulate``: a map consistent with its keyframes (smooth trajectory) over the
            lower ATE that ``keep`` gets on KITTI 07.
        frame_correction: how the frames between keyframes follow the keyframes the backend moved
            (:mod:`vslam.backend.frame_poses`): ``reference`` (rigidly with their reference keyframe,
            ORB-SLAM) or ``interpolate`` (the corrections of the keyframes before and after the frame,
            blended by time; the frame just before a keyframe is one frame of tracking from it).
            Local BA, loop closing off, ATE m, reference -> interpolate: KITTI 06 stereo 0.0561 ->
            0.0557, KITTI 07 mono 0.340 -> 0.339, fr1/desk 9 frames 0.00468 -> 0.00463, EuRoC V1_01
            40 frames 0.00089 -> 0.00088 (with the u_right RGB-D residual); synthetic RGB-D (exact
            ground truth, 60 frames) 0.0057 -> 0.0040.
    """

    type: Literal["graph", "ekf"] = "graph"
    local_ba: bool = True
    mode: Literal["deterministic", "realtime"] = "deterministic"
    final_ba: bool = False
    covisible_keyframes: int = 10
    max_fixed_keyframes: int = 20
    mono_min_observations: int = 3
    mono_min_multiview_points: int = 100
    mono_left_out: Literal["keep", "transport", "retriangulate"] = "retriangulate"
    cull_min_observations: int = 2
    cull_keyframes: bool = False
    redundant_ratio: float = 0.9
    stereo_far_baselines: float = 35.0
    depthless_min_parallax_deg: float = 1.15
    fuse: bool = True
    fuse_radius_px: float = 4.0
    fuse_max_descriptor_distance: float = 50.0
    fuse_mono: bool = False
    local: LocalBAConfig = field(default_factory=LocalBAConfig)
    global_ba: GlobalBAConfig = field(default_factory=GlobalBAConfig)
    pose_graph: PoseGraphConfig = field(default_factory=PoseGraphConfig)
    ekf: EKFConfig = field(default_factory=EKFConfig)

    frame_correction: Literal["reference", "interpolate"] = "interpolate"

    def __post_init__(self) -> None:
        if self.frame_correction not in ("reference", "interpolate"):
            raise ConfigError(f"backend frame_correction must be 'reference' or 'interpolate', got {self.frame_correction!r}")
        if self.mono_min_observations < 2:
            raise ConfigError(f"backend mono_min_observations must be >= 2 (a monocular point needs two views), "
                              f"got {self.mono_min_observations}")
