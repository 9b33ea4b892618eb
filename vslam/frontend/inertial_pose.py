"""Inertial pose optimization of a tracked frame: pose, velocity and biases against the IMU motion
since the last keyframe and the frame's reprojections (ORB-SLAM3's
``Optimizer::PoseInertialOptimizationLastKeyFrame``, Campos et al., T-RO 2021, sec. VI-B).

Cost, over the frame's state ``x = (T_world_imu, v, b)`` (15 DoF; the keyframe's state ``(T_k, v_k,
b_k)`` is held fixed: its visual-inertial BA estimate)::

    sum_i rho(e_i^T Omega_i e_i)  +  ||r_I(k, frame)||^2_Sigma

``e_i`` the reprojection errors of the frame's inlier map points (held fixed; ``(u, v)`` or rectified
stereo ``(u, v, u_right)``, ``Omega = I / sigma^2``, Huber ``rho``), ``r_I`` GTSAM's
``CombinedImuFactor`` from the keyframe to the frame (preintegrated rotation / velocity / position
deltas at the keyframe's biases, and the bias random walk between the two biases; Forster et al.
T-RO 2017). Levenberg-Marquardt on the 15 x 15 normal equations; the pose tangent is GTSAM's (right
perturbation of ``T_world_imu``, rotation first), so the IMU Jacobian is GTSAM's own and the
reprojection's is the visual pose refinement's (:func:`vslam.geometry.pnp.refine_pose`, its compiled
per-point kernel) chained through ``T_cam_imu`` (:class:`_Reprojection`; a NumPy twin of it cost
~1.5x the time per frame and gave the same trajectories, ATE equal to 1e-14 m on MH_01 80). As
ORB-SLAM3, :data:`ROUNDS` rounds, each ending with a chi-square classification of the
observations (5.991 / 7.815), the Huber kernel dropped in the last round.

Example::

    res = optimize_inertial_pose(T_world_cam, v, bias, anchor, pim, X_world, uv, sigma, u_right,
                                 (fx, fy, cx, cy), bf, calib.T_imu_cam)
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from vslam.geometry.lie import hat, inv_se3
from vslam.geometry.pnp import _PoseResiduals
from vslam.inertial import ImuBias
from vslam.inertial.gtsam_values import StateWriter

#: Rounds of (LM iterations per round) and whether the Huber kernel is on: ORB-SLAM3 runs 4 rounds of
#: 10 g2o iterations, the kernel off in the last; 3 short rounds here (measured: per-frame cost, same ATE).
ROUNDS = ((3, True), (2, True), (2, False))
RELATIVE_TOLERANCE = 1e-3  # a round ends when an iteration lowers the cost by less than this fraction
MIN_POINTS = 10  # fewer inliers: no optimization (the visual pose and the IMU prediction's velocity stay)


@dataclass(frozen=True)
class InertialAnchor:
    """The fixed state the frame is tied to: the last keyframe's time (camera clock), pose,
    velocity (world, m/s) and biases."""

    timestamp: float
    T_world_cam: np.ndarray
    velocity: np.ndarray
    bias: ImuBias


@dataclass(frozen=True)
class InertialPoseResult:
    """The optimized frame state: ``T_world_cam``, ``velocity (3,)`` world m/s, ``bias``; ``inliers (N,)``
    the chi-square test at the end; ``imu_chi2`` the IMU factor's squared whitened error."""

    T_world_cam: np.ndarray
    velocity: np.ndarray
    bias: ImuBias
    inliers: np.ndarray
    iterations: int
    imu_chi2: float


class _Reprojection:
    """The frame's reprojections on the pose tangent of the IMU (module docstring): the residuals and
    Jacobians of :func:`vslam.geometry.pnp.refine_pose` (``_PoseResiduals``, left perturbation ``xi``
    of ``T_cam_world``, translation first) chained by ``xi = M delta``, ``M = -P Ad(T_cam_imu)``
    (``T_cam_world(delta) = T_cam_imu Exp(-delta) T_imu_world = Exp(-Ad(T_cam_imu) delta) T_cam_world``;
    ``P`` swaps GTSAM's rotation-first halves)."""

    def __init__(self, X_world, uv, sigma, u_right, intrinsics, bf, T_cam_imu) -> None:
        fx, fy, cx, cy = (float(x) for x in intrinsics)
        K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
        bf = float(bf or 0.0)
        ur = None if u_right is None or bf <= 0 else np.asarray(u_right, float)
        self.res = _PoseResiduals.build(np.asarray(X_world, float), np.asarray(uv, float), K, sigma, ur, bf)
        self.no_huber = replace(self.res, delta=np.full(len(self.res.delta), np.inf))
        self.any_r = bool(self.res.has_r.any())
        n = len(self.res.u_obs)
        self.A = np.empty((6, (3 if self.any_r else 2) * n))
        self.r = np.empty(self.A.shape[1])
        self.info, self.chi2_max = self.res.info, self.res.chi2
        self.T_cam_imu = T_cam_imu
        R, t = T_cam_imu[:3, :3], T_cam_imu[:3, 3]
        Ad = np.zeros((6, 6))
        Ad[:3, :3] = Ad[3:, 3:] = R
        Ad[3:, :3] = hat(t) @ R
        self.M = -np.vstack([Ad[3:], Ad[:3]])

    def chi2(self, T_world_imu: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(T_cam_world, chi2 (N,))`` at the IMU pose: information-weighted squared errors, ``inf``
        within 1 mm of the camera plane or behind it."""
        T_cw = self.T_cam_imu @ inv_se3(T_world_imu)
        res = self.res
        Xc, z, iz, u, v = res.project(T_cw)
        e2 = (u - res.u_obs) ** 2 + (v - res.v_obs) ** 2
        e2 += np.where(res.has_r, ((u - res.bf * iz) - res.ur) ** 2, 0.0)
        chi2 = res.info * e2
        chi2[~(Xc[2] > 1e-3)] = np.inf
        return T_cw, chi2

    def normal_equations(self, T_cw: np.ndarray, active: np.ndarray, huber: bool) -> tuple[np.ndarray, np.ndarray]:
        """``(H (6, 6), g (6,))`` on the IMU pose tangent (``H dx = g``), the active observations
        IRLS-weighted (``info``, times Huber's weight with the threshold ``sqrt(chi2_max)``)."""
        (self.res if huber else self.no_huber).linearize(T_cw, active, self.A, self.r, self.any_r)
        JM = self.M.T @ self.A
        return JM @ JM.T, -(JM @ self.r)


def _robust(chi2, active, huber, chi2_max) -> float:
    c = np.where(active, chi2, 0.0)
    if huber:
        k2 = chi2_max
        c = np.where(c <= k2, c, 2.0 * np.sqrt(k2 * c) - k2)
    return float(np.sum(c[np.isfinite(c)])) + 1e6 * float(np.sum(active & ~np.isfinite(chi2)))


def _initial_values(fixed: list):
    """GTSAM values: the anchor's keys ``0, 1, 2`` at ``fixed`` and the frame's ``3, 4, 5`` started there."""
    vals = StateWriter([1, 4], [2, 5]).values([fixed[1][1]] * 2, [fixed[2][1].vector()] * 2)
    vals.insert(0, fixed[0][1])
    vals.insert(3, fixed[0][1])
    return vals


def optimize_inertial_pose(T_world_cam: np.ndarray, velocity: np.ndarray, bias: ImuBias, anchor: InertialAnchor,
                           pim, X_world: np.ndarray, uv: np.ndarray, sigma: np.ndarray, u_right: np.ndarray | None,
                           intrinsics: tuple[float, float, float, float], bf: float | None,
                           T_imu_cam: np.ndarray) -> InertialPoseResult:
    """The frame's optimized state (module docstring). ``T_world_cam``, ``velocity``, ``bias``: the
    starting point (the visual pose, the IMU prediction's velocity and biases); ``pim``: the
    :class:`gtsam.PreintegratedCombinedMeasurements` from the anchor keyframe to the frame (at the
    anchor's biases); ``X_world (N, 3)`` the frame's inlier map points, ``uv (N, 2)`` their
    undistorted pixels, ``sigma (N,)`` pixel stds, ``u_right (N,)`` rectified right columns (NaN:
    none; None: monocular), ``bf`` ``fx`` times the (virtual) baseline."""
    import gtsam

    T_cam_imu = inv_se3(T_imu_cam)
    rep = _Reprojection(X_world, uv, sigma, u_right, intrinsics, bf, T_cam_imu)
    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.CombinedImuFactor(0, 1, 3, 4, 2, 5, pim))
    fixed = [(0, gtsam.Pose3(anchor.T_world_cam @ T_cam_imu)), (1, np.asarray(anchor.velocity, float)),
             (2, anchor.bias.to_gtsam())]

    vals = _initial_values(fixed)
    writer = StateWriter([4], [5])
    ordering = gtsam.Ordering([3, 4, 5, 0, 1, 2])
    held: list = [None]  # the state (array objects) vals holds now: an accepted step is not written twice

    def values(T_wi, v, b_vec):  # the frame's keys updated in place (one Values for the whole solve)
        if held[0] is None or any(a is not b for a, b in zip(held[0], (T_wi, v, b_vec))):
            vals.update(3, gtsam.Pose3(T_wi))
            writer.write(vals, [v], [b_vec])
            held[0] = (T_wi, v, b_vec)
        return vals

    def imu_linear(T_wi, v, b_vec):  # the frame's columns first: pose 6, velocity 3, biases 6
        A, rhs = graph.linearize(values(T_wi, v, b_vec)).jacobian(ordering)
        return np.asarray(A)[:, :15], np.asarray(rhs, float).reshape(-1)

    T_wi = np.asarray(T_world_cam, float) @ T_cam_imu
    v = np.asarray(velocity, float).reshape(3).copy()
    b_vec = bias.to_gtsam().vector().copy()  # GTSAM order: accelerometer, gyro
    T_cw, chi2 = rep.chi2(T_wi)
    active = chi2 <= rep.chi2_max * 4.0   # the tracker's inliers; gross ones wait for the classification
    iterations = 0
    for n_iter, huber in ROUNDS:
        lam = 1e-3
        cost = _robust(chi2, active, huber, rep.chi2_max) + 2.0 * graph.error(values(T_wi, v, b_vec))
        for _ in range(n_iter):
            iterations += 1
            Hp, gp = rep.normal_equations(T_cw, active & np.isfinite(chi2), huber)
            A, rhs = imu_linear(T_wi, v, b_vec)
            H = A.T @ A
            g = A.T @ rhs
            H[:6, :6] += Hp
            g[:6] += gp
            while True:
                dx = np.linalg.solve(H + lam * np.diag(np.diag(H) + 1e-9), g)
                T_new = np.asarray(gtsam.Pose3(T_wi).retract(dx[:6]).matrix())
                v_new, b_new = v + dx[6:9], b_vec + dx[9:]
                T_cw_n, chi2_n = rep.chi2(T_new)
                new_cost = _robust(chi2_n, active, huber, rep.chi2_max) + 2.0 * graph.error(values(T_new, v_new, b_new))
                if new_cost < cost or lam > 1e6:
                    break
                lam *= 10.0
            if new_cost >= cost:
                break
            small = cost - new_cost <= RELATIVE_TOLERANCE * cost
            T_wi, v, b_vec, T_cw, chi2, cost = T_new, v_new, b_new, T_cw_n, chi2_n, new_cost
            lam = max(lam / 10.0, 1e-7)
            if small:
                break
        active = chi2 <= rep.chi2_max   # ORB-SLAM3: re-classified after each round (outliers may return)
    imu_chi2 = 2.0 * float(graph.error(values(T_wi, v, b_vec)))
    return InertialPoseResult(T_wi @ np.asarray(T_imu_cam, float), v, ImuBias(b_vec[3:], b_vec[:3]), active,
                              iterations, imu_chi2)
