"""Visual-inertial initialization by inertial-only MAP estimation (Campos, Montiel, Gomez Rodriguez,
Tardos, "Inertial-only optimization for visual-inertial initialization", ICRA 2020; ORB-SLAM3's
``LocalMapping::InitializeIMU`` / ``Optimizer::InertialOptimization``).

Given keyframe times and their visual poses ``T_world_cam`` (up to scale for monocular), the IMU
samples and the calibration, it estimates, with the visual poses held fixed:

* the gravity direction in the visual world (2 DoF, a :class:`gtsam.Unit3`), returned as
  ``R_world_gravityaligned`` (``R_wg``: gravity-aligned frame -> visual world; the aligned frame is
  z up, gravity ``-z``, its yaw the smallest rotation from the visual world);
* the scale ``s`` (monocular; 1 and constant for stereo / RGB-D), metres per visual unit;
* the keyframe velocities and one gyro and one accelerometer bias for the window, with a Gaussian
  prior on each bias (the paper's ``p(b)``; ORB-SLAM3 ``EdgePriorGyro`` / ``EdgePriorAcc``).

The problem is a GTSAM factor graph: one inertial factor per keyframe interval
(:mod:`vslam.backend.inertial_residual`, the preintegration of :mod:`vslam.inertial`) and the two
bias priors, solved by Levenberg-Marquardt. Its initial guess is linear: the gyro bias from the
rotation residuals (one Gauss-Newton step), then velocities, gravity vector and scale by linear
least squares (the VINS-Mono "visual-inertial alignment", Qin et al. T-RO 2018 sec. V-B).

Example (``ds`` an EuRoC dataset, ``t``, ``T`` the keyframes of a stereo run)::

    res = initialize_inertial(t, T, ds.imu, ds.imu_calibration.with_camera(ds.T_cam0_rect))
    if res.success:
        T_aligned = gravity_aligned_poses(T, res)          # z up, metric
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field, replace

import numpy as np

from vslam.backend.inertial_residual import (
    ImuInterval, KeyframePair, imu_interval, inertial_factor, make_pair, residual,
)
from vslam.inertial import ImuBias, ImuCalibration, ImuMeasurements, make_params, rotation_to_up
from vslam.trajectory import Trajectory

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class InertialInitConfig:
    """Settings of :func:`initialize_inertial`.

    Attributes:
        min_keyframes: fewer keyframes are refused (ORB-SLAM3 ``InitializeIMU``: 10).
        min_duration_s: a shorter window is refused (ORB-SLAM3: 1 s stereo; it waits 2 s for
            monocular, which the caller chooses by the window it passes).
        min_excitation: refuse when the std (norm over axes) of the world-frame specific force
            averaged per interval is below this, m/s^2: no acceleration change, no scale or
            accelerometer bias (the idea of VINS-Mono's excitation test). Measured: EuRoC V1_01 at
            rest, motors on: 0.043; the synthetic loop: 0.24 (its 2 s still give the scale to 3.7 %,
            ``std_scale``); MH_01 hand-held: 1.7.
        gyro_bias_sigma: std of the zero-mean gyro bias prior, rad/s: 0.1, ORB-SLAM3's first
            ``InitializeIMU(priorG = 1e2, ...)`` (an information, 1 / sigma^2).
        accel_bias_sigma: std of the zero-mean accelerometer bias prior, m/s^2; None takes
            ORB-SLAM3's first ``InitializeIMU``: ``priorA`` 1e10 monocular (1e-5: the bias held at
            zero while the scale is unknown; over ~2 s of noisy monocular poses a free ``b_a`` trades
            against scale and tilt) and 1e5 otherwise (3.2e-3).
        max_iterations: Levenberg-Marquardt iterations.
    """

    min_keyframes: int = 10
    min_duration_s: float = 1.0
    min_excitation: float = 0.1
    gyro_bias_sigma: float = 0.1
    accel_bias_sigma: float | None = None
    max_iterations: int = 100


@dataclass(frozen=True)
class InertialInitResult:
    """What :func:`initialize_inertial` found.

    Attributes:
        success: False when refused or failed; ``reason`` says why ("ok" on success).
        R_world_gravityaligned: ``(3, 3)`` gravity-aligned frame (z up) -> visual world.
        scale: metres per visual unit (1 when fixed).
        velocities: ``(K, 3)`` IMU velocities in the gravity-aligned frame, m/s.
        bias: the window's gyro / accelerometer biases.
        cost: final GTSAM graph error (``0.5 * sum of squared whitened residuals``);
            ``initial_cost`` the same at the linear initial guess.
        gravity_world: ``(3,)`` gravity in the visual world frame, m/s^2.
        timestamps: ``(K,)`` keyframe times (camera clock). duration_s: their span.
        iterations: LM iterations. solve_time_s: wall time of the whole estimate.
        std_scale, std_gravity_deg, std_gyro_bias (3,), std_accel_bias (3,): posterior standard
            deviations (GTSAM marginals at the optimum; the gravity's is the larger axis of its
            2-DoF tangent, in degrees): how well the window determined each.
    """

    success: bool
    reason: str
    R_world_gravityaligned: np.ndarray
    scale: float
    velocities: np.ndarray
    bias: ImuBias
    cost: float
    initial_cost: float
    gravity_world: np.ndarray
    timestamps: np.ndarray
    duration_s: float
    iterations: int = 0
    solve_time_s: float = 0.0
    std_scale: float = float("nan")
    std_gravity_deg: float = float("nan")
    std_gyro_bias: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    std_accel_bias: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))


def _refused(reason: str, timestamps: np.ndarray, started: float) -> InertialInitResult:
    log.info("inertial initialization refused: %s", reason)
    K = len(timestamps)
    return InertialInitResult(False, reason, np.eye(3), 1.0, np.zeros((K, 3)), ImuBias(), float("nan"),
                              float("nan"), np.full(3, np.nan), timestamps,
                              float(timestamps[-1] - timestamps[0]) if K else 0.0,
                              solve_time_s=time.perf_counter() - started)


def _check_window(t: np.ndarray, imu: ImuMeasurements, calib: ImuCalibration, cfg: InertialInitConfig) -> str | None:
    """Why the window cannot be used (a sentence), or None."""
    if len(t) < cfg.min_keyframes:
        return f"too few keyframes: {len(t)} < {cfg.min_keyframes}"
    if np.any(np.diff(t) <= 0):
        return "keyframe timestamps are not strictly increasing"
    if t[-1] - t[0] < cfg.min_duration_s:
        return f"window too short: {t[-1] - t[0]:.2f} s < {cfg.min_duration_s:g} s"
    lo, hi = calib.imu_time(t[0]), calib.imu_time(t[-1])
    if imu is None or len(imu) < 2 or imu.timestamps[0] > lo or imu.timestamps[-1] < hi:
        return f"the IMU samples do not cover the keyframes ({lo:.3f} .. {hi:.3f} s on the IMU clock)"
    return None


def _excitation(pairs: list[KeyframePair], intervals: list[ImuInterval]) -> float:
    """Norm of the per-axis std of ``R_i dv / dt`` (world-frame specific force per interval)."""
    f = np.array([p.R_i @ itv.dv0 / itv.dt for p, itv in zip(pairs, intervals)])
    return float(np.linalg.norm(f.std(axis=0)))


def _gyro_bias_guess(pairs: list[KeyframePair], intervals: list[ImuInterval], b0: np.ndarray,
                     sigma: float) -> np.ndarray:
    """One Gauss-Newton step on the rotation residuals (weighted by their covariance) and the
    zero-mean prior, from ``b0``: the gyro bias (VINS-Mono ``solveGyroscopeBias``)."""
    A = np.eye(3) / sigma**2
    rhs = -A @ b0[:3]
    for pair, itv in zip(pairs, intervals):
        r, J = residual(pair, itv, np.array([0.0, 0.0, 1.0]), np.zeros((3, 2)), 0.0, np.zeros(3), np.zeros(3),
                        b0, 9.81, jacobians=True)   # only the rotation rows are used: no gravity, scale, velocity
        W = np.linalg.inv(itv.cov[:3, :3])
        A += J[4][:3].T @ W @ J[4][:3]
        rhs -= J[4][:3].T @ W @ r[:3]
    b = b0.copy()
    b[:3] += np.linalg.solve(A, rhs)
    return b


def _linear_guess(pairs: list[KeyframePair], intervals: list[ImuInterval], b: np.ndarray,
                  mono: bool) -> tuple[np.ndarray, np.ndarray, float]:
    """Velocities ``(K, 3)``, gravity ``(3,)`` and scale by weighted linear least squares on the
    position and velocity deltas at bias ``b`` (gravity magnitude free; VINS-Mono
    ``LinearAlignment``)::

        v_j - v_i - g dt                             = R_i dv
        s (c_j - c_i) - v_i dt - g dt^2 / 2          = R_i dp - (q_j - q_i)
    """
    K = len(pairs) + 1
    n = 3 * K + 3 + (1 if mono else 0)
    rows, rhs = [], []
    I3 = np.eye(3)
    for k, (pair, itv) in enumerate(zip(pairs, intervals)):
        _theta, _dR, dp, dv = itv.deltas(b)
        dt = itv.dt
        wp = 1.0 / np.sqrt(np.mean(np.diag(itv.cov[3:6, 3:6])))
        wv = 1.0 / np.sqrt(np.mean(np.diag(itv.cov[6:9, 6:9])))
        Av = np.zeros((3, n))
        Av[:, 3 * k:3 * k + 3], Av[:, 3 * k + 3:3 * k + 6], Av[:, 3 * K:3 * K + 3] = -I3, I3, -dt * I3
        Ap = np.zeros((3, n))
        Ap[:, 3 * k:3 * k + 3], Ap[:, 3 * K:3 * K + 3] = -dt * I3, -0.5 * dt * dt * I3
        bp = pair.R_i @ dp - (pair.q_j - pair.q_i)
        if mono:
            Ap[:, -1] = pair.c_j - pair.c_i
        else:
            bp = bp - (pair.c_j - pair.c_i)
        rows += [wv * Av, wp * Ap]
        rhs += [wv * (pair.R_i @ dv), wp * bp]
    from threadpoolctl import threadpool_limits

    with threadpool_limits(1, user_api="blas"):  # a ~100-column problem: threads only contend
        x = np.linalg.lstsq(np.vstack(rows), np.concatenate(rhs), rcond=None)[0]
    return x[:3 * K].reshape(K, 3), x[3 * K:3 * K + 3], float(x[-1]) if mono else 1.0


def _build_graph(pairs, intervals, calib: ImuCalibration, cfg: InertialInitConfig, mono: bool,
                 v0: np.ndarray, g0: np.ndarray, s0: float, b0: np.ndarray):
    """The factor graph (one inertial factor per interval, the two bias priors) and its initial
    values. Gauge: none left free (yaw and position are not unknowns; the up direction has 2 DoF)."""
    import gtsam

    K = len(pairs) + 1
    keys = {"u": 0, "s": 1, "bg": 2, "ba": 3}
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    values.insert(keys["u"], gtsam.Unit3(-g0 / np.linalg.norm(g0)))
    if mono:
        values.insert(keys["s"], np.array([np.log(s0)]))
    values.insert(keys["bg"], b0[:3].copy())
    values.insert(keys["ba"], b0[3:].copy())
    for k in range(K):
        values.insert(10 + k, v0[k].copy())
    for k, (pair, itv) in enumerate(zip(pairs, intervals)):
        graph.add(inertial_factor(pair, itv, {**keys, "v_i": 10 + k, "v_j": 11 + k}, calib.gravity,
                                  None if mono else 0.0))
    graph.add(gtsam.PriorFactorVector(keys["bg"], np.zeros(3), gtsam.noiseModel.Isotropic.Sigma(3, cfg.gyro_bias_sigma)))
    sigma_a = cfg.accel_bias_sigma if cfg.accel_bias_sigma is not None else (1e-5 if mono else 1e5**-0.5)
    graph.add(gtsam.PriorFactorVector(keys["ba"], np.zeros(3), gtsam.noiseModel.Isotropic.Sigma(3, sigma_a)))
    return graph, values, keys


def initialize_inertial(timestamps: np.ndarray, T_world_cam: np.ndarray, imu: ImuMeasurements,
                        calib: ImuCalibration, monocular: bool = False,
                        config: InertialInitConfig = InertialInitConfig()) -> InertialInitResult:
    """Gravity direction, scale (``monocular``), velocities and biases of a keyframe window by
    inertial-only MAP estimation (module docstring), the visual poses held fixed.

    ``timestamps (K,)`` camera clock, ``T_world_cam (K, 4, 4)`` of the camera ``calib`` refers to
    (``calib.T_imu_cam``; EuRoC stereo: ``calib.with_camera(ds.T_cam0_rect)``). A window with too
    few keyframes, too short, not covered by the IMU or without acceleration change is refused
    (``success`` False, ``reason`` says why), as is an estimate that is not finite or has a
    non-positive scale.
    """
    import gtsam

    started = time.perf_counter()
    t = np.asarray(timestamps, float).reshape(-1)
    T = np.asarray(T_world_cam, float).reshape(-1, 4, 4)
    if len(T) != len(t):
        raise ValueError(f"{len(t)} keyframe timestamps but {len(T)} poses")
    why = _check_window(t, imu, calib, config)
    if why:
        return _refused(why, t, started)
    params = make_params(calib, np.zeros(3))
    t_imu = calib.imu_time(t)
    intervals = [imu_interval(imu, t_imu[k], t_imu[k + 1], params, ImuBias()) for k in range(len(t) - 1)]
    pairs = [make_pair(T[k], T[k + 1], calib) for k in range(len(t) - 1)]
    excitation = _excitation(pairs, intervals)
    if excitation < config.min_excitation:
        return _refused(f"insufficient excitation: specific force std {excitation:.3f} < "
                        f"{config.min_excitation:g} m/s^2", t, started)
    b0 = _gyro_bias_guess(pairs, intervals, np.zeros(6), config.gyro_bias_sigma)
    v0, g0, s0 = _linear_guess(pairs, intervals, b0, monocular)
    if not (np.all(np.isfinite(g0)) and np.linalg.norm(g0) > 1e-6 and np.isfinite(s0)):
        return _refused("the linear initial guess is degenerate", t, started)
    if s0 <= 0:  # a poor linear guess (noisy poses): the MAP starts from the visual scale instead
        log.info("inertial initialization: linear scale guess %.3f <= 0, starting from 1", s0)
        v0, g0, s0 = _linear_guess(pairs, intervals, b0, False)
    graph, values, keys = _build_graph(pairs, intervals, calib, config, monocular, v0, g0, s0, b0)
    lm = gtsam.LevenbergMarquardtParams()
    lm.setMaxIterations(config.max_iterations)
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, values, lm)
    initial_cost = float(graph.error(values))
    est = optimizer.optimize()
    return _result(est, keys, graph, t, monocular, calib, initial_cost, int(optimizer.iterations()), started)


def _result(est, keys: dict, graph, t: np.ndarray, mono: bool, calib: ImuCalibration, initial_cost: float,
            iterations: int, started: float) -> InertialInitResult:
    """The :class:`InertialInitResult` of the optimized values (or a failure when not finite)."""
    up = np.asarray(est.atUnit3(keys["u"]).point3())
    s = float(np.exp(est.atVector(keys["s"])[0])) if mono else 1.0
    V = np.array([est.atVector(10 + k) for k in range(len(t))])
    bias = ImuBias(est.atVector(keys["bg"]), est.atVector(keys["ba"]))
    cost = float(graph.error(est))
    if not (np.isfinite(cost) and np.isfinite(s) and np.all(np.isfinite(V)) and s > 0):
        return _refused(f"the optimization did not converge (cost {cost}, scale {s})", t, started)
    R_wg = rotation_to_up(up).T   # +z -> up: the smallest rotation (yaw-free, as ORB-SLAM3's initial Rwg)
    res = InertialInitResult(True, "ok", R_wg, s, V @ R_wg, bias, cost, initial_cost, -calib.gravity * up, t,
                             float(t[-1] - t[0]), iterations, 0.0, **_posterior_stds(graph, est, keys, mono, s))
    res = replace(res, solve_time_s=time.perf_counter() - started)
    log.info("inertial initialization: %d keyframes over %.2f s, scale %.4f, b_g %s, b_a %s, cost %.4g -> %.4g "
             "(%d iterations, %.0f ms)", len(t), res.duration_s, s, np.round(bias.gyro, 4), np.round(bias.accel, 3),
             initial_cost, cost, iterations, 1e3 * res.solve_time_s)
    return res


def _posterior_stds(graph, est, keys: dict, mono: bool, s: float) -> dict:
    """The ``std_*`` fields of :class:`InertialInitResult` from GTSAM's marginal covariances."""
    import gtsam

    try:
        m = gtsam.Marginals(graph, est)
        C_u = np.asarray(m.marginalCovariance(keys["u"]))
        return {
            "std_scale": s * float(np.sqrt(m.marginalCovariance(keys["s"])[0, 0])) if mono else 0.0,
            "std_gravity_deg": float(np.degrees(np.sqrt(np.linalg.eigvalsh(C_u).max()))),
            "std_gyro_bias": np.sqrt(np.diag(m.marginalCovariance(keys["bg"]))),
            "std_accel_bias": np.sqrt(np.diag(m.marginalCovariance(keys["ba"]))),
        }
    except RuntimeError as exc:  # an indeterminant system: leave them unknown
        log.warning("inertial initialization: no marginals (%s)", exc)
        return {}


def gravity_aligned_poses(T_world_cam: np.ndarray, result: InertialInitResult) -> np.ndarray:
    """``T_world_cam (N, 4, 4)`` (visual world, visual units) -> the gravity-aligned, metric world
    of ``result``: ``R = R_wg^T R_wc``, ``t = s R_wg^T t_wc``. A refused result raises ValueError."""
    if not result.success:
        raise ValueError(f"the inertial initialization did not succeed ({result.reason}); nothing to apply")
    T = np.array(T_world_cam, float).reshape(-1, 4, 4)
    Rt = result.R_world_gravityaligned.T
    T[:, :3, :3] = Rt @ T[:, :3, :3]
    T[:, :3, 3] = result.scale * T[:, :3, 3] @ Rt.T
    return T


def gravity_aligned_trajectory(trajectory: Trajectory, result: InertialInitResult) -> Trajectory:
    """:func:`gravity_aligned_poses` of a whole :class:`Trajectory`."""
    return Trajectory(trajectory.timestamps.copy(), gravity_aligned_poses(trajectory.T_world_cam, result))
