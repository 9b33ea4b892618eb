"""Visual-inertial bundle adjustment: reprojection + IMU preintegration + bias random walk, jointly.

The cost (ORB-SLAM3's ``LocalInertialBA`` / ``FullInertialBA``, Campos et al., T-RO 2021, eq. 7)::

    sum_obs rho(e_ij^T Omega_ij e_ij)  +  sum_k ||r_I(k, k+1)||^2_Sigma_I  [+ bias prior]

``e_ij`` the reprojection errors of :mod:`vslam.backend.bundle_adjustment` (mono / stereo / RGB-D,
Huber ``rho``, a robust pass then a refinement without the outliers), ``r_I`` GTSAM's
``CombinedImuFactor`` between consecutive keyframes of the :class:`ImuChain` (Forster et al., T-RO
2017: preintegrated rotation, velocity and position deltas, first-order bias correction, and the
bias random walk between the two keyframes' biases, whitened by the preintegration covariance).
Per keyframe of the chain the state is ``T_world_cam``, the IMU velocity (world, m/s) and the biases.

The solver is the Schur-complement Levenberg-Marquardt of :mod:`vslam.backend.schur_lm` (its
compiled kernels linearize the reprojections and eliminate the points), extended by the velocity and
bias blocks: the reduced camera system ``S`` (``6 n_c``) is embedded in the ``6 n_c + 9 n_s``
system, the IMU factors' Jacobians (linearized by GTSAM, in C++) are added to it, and the point
steps are back-substituted from the camera steps as before. GTSAM's pose tangent (right
perturbation of ``T_world_imu``, rotation first) maps to the solver's (left perturbation of
``T_cam_world``, translation first) by ``xi = -Ad(T_imu_cam) P delta`` (``P`` swaps the halves):
``T_world_imu (+) xi = T_world_cam Exp(-delta) T_cam_imu``.

Gauge: the problem's fixed keyframes (poses) and the chain's keyframes without a variable pose
(their velocity and biases constant too: the window's old end, ORB-SLAM3's fixed previous
keyframe); a full VI-BA adds a zero-mean prior on the first keyframe's biases.
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg

from vslam.backend import schur_kernels, schur_lm
# the problem <-> solver conversions of the visual BA (one place that turns problems into observations)
from vslam.backend.bundle_adjustment import (
    _cam_var, _chi2_thresholds, _join_poses, _observations, _split_poses, _stats,
)
from vslam.backend.config import LocalBAConfig
from vslam.backend.problem import BAProblem, BAResult
from vslam.errors import GeometryError
from vslam.inertial.gtsam_values import StateWriter

log = logging.getLogger(__name__)

#: GTSAM bias tangent is (accelerometer, gyro); ours (the ``imu_bias`` contract) is (gyro, accelerometer).
_SWAP = np.r_[3, 4, 5, 0, 1, 2]


def _cat(parts: list) -> np.ndarray:
    """Index arrays concatenated (int64; empty when none)."""
    return np.concatenate(parts).astype(np.int64) if parts else np.zeros(0, np.int64)


@dataclass
class ImuChain:
    """The IMU part of a VI-BA: keyframes consecutive in time and the motion between them.

    Attributes:
        kf_ids: ``(N,)`` keyframe ids in time order.
        T_world_cam: ``(N, 4, 4)`` their poses (used for keyframes that are not variables of the problem).
        velocity: ``(N, 3)`` IMU velocities, world frame, m/s (initial values; constants where the pose is fixed).
        bias: ``(N, 6)`` gyro then accelerometer biases (the same).
        pims: ``N - 1`` :class:`gtsam.PreintegratedCombinedMeasurements` between consecutive keyframes
            (None: no IMU factor across that gap).
        bias_prior: ``(sigma_gyro, sigma_accel)`` of a zero-mean prior on the first variable
            keyframe's biases, or None.
        free: ``(N,)`` keyframes whose velocity and biases are variables even where the pose is
            fixed (a full VI-BA's first keyframe); None: none. (A variable pose has a variable state.)
    """

    kf_ids: np.ndarray
    T_world_cam: np.ndarray
    velocity: np.ndarray
    bias: np.ndarray
    pims: list
    bias_prior: tuple[float, float] | None = None
    free: np.ndarray | None = None


@dataclass
class InertialBAResult(BAResult):
    """:class:`BAResult` plus the chain's estimated states: ``{kf_id: velocity (3,)}`` and
    ``{kf_id: bias (6,) gyro, accel}`` for the keyframes whose state was a variable, and the IMU cost
    (sum of squared whitened IMU residuals) before and after."""

    velocities: dict = field(default_factory=dict)
    biases: dict = field(default_factory=dict)
    imu_cost: tuple[float, float] = (0.0, 0.0)


class _ImuTerms:
    """The chain's IMU factors on the solver's variables (module docstring)."""

    def __init__(self, chain: ImuChain, problem: BAProblem, cam_var: np.ndarray, T_imu_cam: np.ndarray) -> None:
        import gtsam

        self.chain = chain
        self.T_cam_imu = np.linalg.inv(T_imu_cam)
        n = len(chain.kf_ids)
        pos = {int(k): i for i, k in enumerate(problem.kf_ids.tolist())}
        self.row = np.array([pos.get(int(k), -1) for k in chain.kf_ids], np.int64)
        self.pose_var = np.array([cam_var[r] if r >= 0 else -1 for r in self.row], np.int64)
        self.n_c = int(cam_var.max(initial=-1)) + 1
        self.state_var = np.full(n, -1, np.int64)
        has = self.pose_var >= 0
        if chain.free is not None:
            has = has | np.asarray(chain.free, bool)
        self.state_var[has] = np.arange(int(has.sum()))
        self.dim = 6 * self.n_c + 9 * int(has.sum())
        P = np.zeros((6, 6))
        P[:3, 3:], P[3:, :3] = np.eye(3), np.eye(3)
        self.D = -np.asarray(gtsam.Pose3(T_imu_cam).AdjointMap()) @ P   # d xi / d delta
        self.v = np.array(chain.velocity, float).reshape(n, 3)
        self.b = np.array(chain.bias, float).reshape(n, 6)
        self.graph = gtsam.NonlinearFactorGraph()
        self.factor_entries: list[tuple[int, int]] = []
        for k, pim in enumerate(chain.pims):
            if pim is None or not (has[k] or has[k + 1]):
                continue
            self.graph.add(gtsam.CombinedImuFactor(3 * k, 3 * k + 1, 3 * k + 3, 3 * k + 4, 3 * k + 2, 3 * k + 5, pim))
            self.factor_entries.append((k, k + 1))
        self.prior_entry = -1
        self._vals = None  # one gtsam.Values, updated in place for each evaluation
        self._held = None  # the (R_cw, t_cw, v, b) arrays _vals holds now
        if chain.bias_prior is not None and has.any():
            e = int(np.flatnonzero(has)[0])
            sg, sa = chain.bias_prior
            noise = gtsam.noiseModel.Diagonal.Sigmas(np.r_[sa, sa, sa, sg, sg, sg])
            self.graph.add(gtsam.PriorFactorConstantBias(3 * e + 2, gtsam.imuBias.ConstantBias(), noise))
            self.prior_entry = e
        self._pose_rows = [int(e) for e in np.flatnonzero(self.row >= 0)]
        self._states = np.flatnonzero(self.state_var >= 0)
        self._writer = StateWriter(3 * self._states + 1, 3 * self._states + 2)
        self._solver_map()

    @property
    def n_factors(self) -> int:
        return self.graph.size()

    def _values(self, R_cw: np.ndarray, t_cw: np.ndarray, v: np.ndarray, b: np.ndarray):
        """The state as GTSAM values, one :class:`gtsam.Values` updated in place: the constant entries
        (poses not in the problem, states that are not variables) written once, the rest each call."""
        import gtsam

        values = self._vals
        first = values is None
        if first:
            values = self._vals = gtsam.Values()
            const = np.flatnonzero(self.state_var < 0)
            StateWriter(3 * const + 1, 3 * const + 2).write(values, v[const], b[const][:, _SWAP])
            for e in np.flatnonzero(self.row < 0):
                values.insert(3 * int(e), gtsam.Pose3(self.chain.T_world_cam[e] @ self.T_cam_imu))
        elif self._held is not None and all(a is h for a, h in zip((R_cw, t_cw, v, b), self._held)):
            return values  # the state written last (an accepted step's cost, then its linearization)
        put = values.insert if first else values.update
        rows = self.row[self._pose_rows]
        T_wc = np.zeros((len(rows), 4, 4))
        T_wc[:, :3, :3] = R_cw[rows].transpose(0, 2, 1)
        T_wc[:, :3, 3] = -np.einsum("nji,nj->ni", R_cw[rows], t_cw[rows])
        T_wc[:, 3, 3] = 1.0
        for e, T in zip(self._pose_rows, T_wc @ self.T_cam_imu):
            put(3 * e, gtsam.Pose3(T))
        self._writer.write(values, v[self._states], b[self._states][:, _SWAP])
        self._held = (R_cw, t_cw, v, b)
        return values

    def cost(self, R_cw, t_cw, v, b) -> float:
        """Sum of squared whitened residuals (no 1/2: the visual cost's convention)."""
        if self.n_factors == 0:
            return 0.0
        return 2.0 * float(self.graph.error(self._values(R_cw, t_cw, v, b)))

    def linearize(self, R_cw, t_cw) -> tuple[np.ndarray, np.ndarray, float]:
        """``(H (dim, dim), g (dim,), cost)`` of the IMU factors at the current state, in the
        solver's variables (``H dx = g`` convention of :mod:`schur_lm`): GTSAM's whitened dense
        Jacobian ``A`` (columns in :attr:`_ordering`) mapped to the solver's columns (:meth:`_solver_map`)."""
        if self.n_factors == 0:
            return np.zeros((self.dim, self.dim)), np.zeros(self.dim), 0.0
        lin = self.graph.linearize(self._values(R_cw, t_cw, self.v, self.b))
        A, rhs = lin.jacobian(self._ordering)
        A, rhs = np.asarray(A), np.asarray(rhs, float).reshape(-1)
        J = np.zeros((A.shape[0], self.dim))
        J[:, self._plain_dst] = A[:, self._plain_src]
        if len(self._pose_src):
            J[:, self._pose_dst] = (A[:, self._pose_src].reshape(-1, 6) @ self.D).reshape(A.shape[0], -1)
        return J.T @ J, J.T @ rhs, float(rhs @ rhs)

    def _solver_map(self) -> None:
        """The GTSAM key ordering of the graph's variables and the column map GTSAM tangent ->
        solver variables: a variable pose's 6 columns times ``D`` (``_pose_src`` -> ``_pose_dst``,
        pose by pose), a velocity's as they are, the biases' (accelerometer, gyro) swapped to
        (gyro, accelerometer) (``_plain_src`` -> ``_plain_dst``); constants are dropped."""
        import gtsam

        keys = {3 * k + j for k, _ in self.factor_entries for j in range(6)}
        if self.prior_entry >= 0:
            keys.add(3 * self.prior_entry + 2)
        keys = sorted(keys)
        self._ordering = gtsam.Ordering(keys)
        pose_src, pose_dst, plain_src, plain_dst = [], [], [], []
        c = 0
        for key in keys:
            e, kind = divmod(key, 3)
            o = 6 * self.n_c + 9 * self.state_var[e]
            if kind == 0 and self.pose_var[e] >= 0:
                pose_src.append(np.arange(c, c + 6))
                pose_dst.append(np.arange(6) + 6 * self.pose_var[e])
            elif kind == 1 and self.state_var[e] >= 0:
                plain_src.append(np.arange(c, c + 3))
                plain_dst.append(np.arange(o, o + 3))
            elif kind == 2 and self.state_var[e] >= 0:
                plain_src.append(c + _SWAP)
                plain_dst.append(np.arange(o + 3, o + 9))
            c += 3 if kind == 1 else 6
        self._pose_src, self._pose_dst = _cat(pose_src), _cat(pose_dst)
        self._plain_src, self._plain_dst = _cat(plain_src), _cat(plain_dst)

    def stepped(self, dx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Velocities and biases after the step ``dx`` (their part, additive)."""
        v, b = self.v.copy(), self.b.copy()
        for e in np.flatnonzero(self.state_var >= 0):
            o = 6 * self.n_c + 9 * self.state_var[e]
            v[e] += dx[o:o + 3]
            b[e] += dx[o + 3:o + 9]
        return v, b


def _solve_spd(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``A^-1 b`` by Cholesky (``A`` is the damped, positive definite normal matrix; as
    :func:`schur_lm._solve_damped`), LU then least squares where it is not."""
    _, x, info = scipy.linalg.lapack.dposv(A, b)
    if info == 0:
        return x
    try:
        return np.linalg.solve(A, b)
    except np.linalg.LinAlgError:
        return np.linalg.lstsq(A, b, rcond=None)[0]


def _lm(R, t, X, terms: _ImuTerms, pr: schur_lm.Prepared, intr, active, huber, max_iterations: int,
        config: LocalBAConfig):
    """Joint LM (module docstring); returns ``(R, t, X, iterations, r, chi2)`` with ``terms.v / .b``
    updated. ``active`` / ``huber`` in the caller's observation order."""
    obs, st = pr.obs, pr.st
    active, huber = pr.sorted_(active), pr.sorted_(huber)
    r, chi2, X_cam = schur_lm._predict(R, t, X, obs, intr, config.min_depth)
    act = active.astype(float) * obs.info
    w_rows = np.stack([act, act, act * obs.stereo if obs.uniform_info else active * obs.info_d * obs.stereo])
    n6 = 6 * st.n_c
    lam = config.lambda_initial
    cost = schur_lm._robust_cost(chi2, active, huber) + terms.cost(R, t, terms.v, terms.b)
    iterations = 0
    for _ in range(max_iterations):
        iterations += 1
        Hcc, gc, W, Hpp, gp = schur_lm._linearize(R, X_cam, r, chi2, w_rows, huber, obs, intr, st)
        Hi, gi, _ = terms.linearize(R, t)
        d_imu = np.diag(Hi).copy()
        while True:
            V = np.empty_like(Hpp)
            schur_kernels.damped_point_inverse(Hpp, float(lam), V)
            S, bc = st.reduce(W, V, gp, gc)
            schur_kernels.add_damped_camera_blocks(S, Hcc, float(lam))
            A, b = Hi.copy(), gi.copy()
            A[:n6, :n6] += S
            b[:n6] += bc
            A[np.arange(n6, terms.dim), np.arange(n6, terms.dim)] += lam * d_imu[n6:] + 1e-12
            dx = _solve_spd(A, b)
            dc = np.ascontiguousarray(dx[:n6])
            dp = st.back_substitute(W, V, gp, dc)
            R_new, t_new, X_new = schur_lm._step(R, t, X, dc.reshape(-1, 6), dp, pr)
            v_new, b_new = terms.stepped(dx)
            r_new, chi2_new, X_cam_new = schur_lm._predict(R_new, t_new, X_new, obs, intr, config.min_depth)
            new_cost = (schur_lm._robust_cost(chi2_new, active, huber, prev=chi2)
                        + terms.cost(R_new, t_new, v_new, b_new))
            if new_cost < cost:
                break
            lam *= schur_lm.LAMBDA_FACTOR
            if lam > schur_lm.LAMBDA_MAX:
                r_out, chi2_out = pr.unsorted(r, chi2)
                return R, t, X, iterations, r_out, chi2_out
        decrease = cost - new_cost
        R, t, X, r, chi2, X_cam, cost = R_new, t_new, X_new, r_new, chi2_new, X_cam_new, new_cost
        terms.v, terms.b = v_new, b_new
        lam = max(lam / schur_lm.LAMBDA_FACTOR, schur_lm.LAMBDA_MIN)
        if decrease <= config.relative_tolerance * max(cost + decrease, 1e-12):
            break
    r_out, chi2_out = pr.unsorted(r, chi2)
    return R, t, X, iterations, r_out, chi2_out


def inertial_bundle_adjustment(problem: BAProblem, chain: ImuChain, T_imu_cam: np.ndarray,
                               config: LocalBAConfig | None = None) -> InertialBAResult:
    """Optimize the non-fixed keyframes of ``problem`` (poses), the states of the chain keyframes
    among them (velocity, biases) and all points, under the reprojection and IMU factors (module
    docstring). Passes as :func:`vslam.backend.bundle_adjustment.local_bundle_adjustment`: a robust
    pass (``iterations_robust``), the chi-square outliers removed, a refinement (``iterations_refine``).
    ``T_imu_cam``: camera -> IMU of the camera the problem's poses belong to."""
    config = config or LocalBAConfig()
    if problem.num_keyframes == 0 or problem.num_observations == 0:
        raise GeometryError("VI-BA needs at least one keyframe and one observation")
    t_start = time.perf_counter()
    cam = problem.camera
    intr = schur_lm.Intrinsics(cam.fx, cam.fy, cam.cx, cam.cy)
    obs = _observations(problem, config)
    fixed = problem.fixed_kf_ids
    if len(fixed) == 0:
        fixed = problem.kf_ids[[int(np.argmin(problem.kf_ids))]]
    cam_var = _cam_var(problem, fixed)
    huber, chi2_max = _chi2_thresholds(obs, config)
    R0, t0 = _split_poses(problem.T_world_cam)
    R, t, X = R0, t0, problem.X_world.copy()
    terms = _ImuTerms(chain, problem, cam_var, T_imu_cam)
    imu_cost0 = terms.cost(R, t, terms.v, terms.b)
    with schur_lm._blas_single_thread():
        pr = schur_lm.prepare(obs, cam_var, len(X))
        build_s = time.perf_counter() - t_start
        active = np.ones(problem.num_observations, bool)
        iterations, now = 0, None
        for n_iter, kernel in ((config.iterations_robust, huber), (config.iterations_refine, None)):
            if n_iter == 0:
                continue
            if kernel is None and config.iterations_robust > 0 and now is not None:
                active = now[1] <= chi2_max
            R, t, X, it, r, chi2 = _lm(R, t, X, terms, pr, intr, active, kernel, n_iter, config)
            iterations += it
            now = (r, chi2)
    if now is None:
        now = schur_lm.residuals(R, t, X, obs, intr, config.min_depth)[:2]
    inliers = now[1] <= chi2_max
    T_world_cam = _join_poses(R, t)
    T_world_cam[cam_var < 0] = problem.T_world_cam[cam_var < 0]
    init_cost, init_rms = _stats(problem, obs, intr, R0, t0, problem.X_world, inliers, config.min_depth)
    final_cost, final_rms = _stats(problem, obs, intr, R, t, X, inliers, config.min_depth, now)
    imu_cost1 = terms.cost(R, t, terms.v, terms.b)
    var = terms.state_var >= 0
    ids = chain.kf_ids[var].tolist()
    total = time.perf_counter() - t_start
    result = InertialBAResult(
        kf_ids=problem.kf_ids.copy(), T_world_cam=T_world_cam, pt_ids=problem.pt_ids.copy(), X_world=X,
        inlier_mask=inliers, initial_cost=init_cost, final_cost=final_cost, initial_rms_px=init_rms,
        final_rms_px=final_rms, iterations=iterations, build_time_s=build_s, solve_time_s=total - build_s,
        time_s=total, solver="schur+imu",
        velocities={int(k): terms.v[e].copy() for k, e in zip(ids, np.flatnonzero(var))},
        biases={int(k): terms.b[e].copy() for k, e in zip(ids, np.flatnonzero(var))},
        imu_cost=(imu_cost0, imu_cost1),
    )
    log.debug("VI-BA: %d keyframes (%d with IMU state), %d points, %d IMU factors, rms %.2f -> %.2f px, "
              "IMU cost %.3g -> %.3g, %d iterations, %.0f ms", problem.num_keyframes, int(var.sum()),
              problem.num_points, terms.n_factors, init_rms, final_rms, imu_cost0, imu_cost1, iterations,
              1e3 * total)
    return result
