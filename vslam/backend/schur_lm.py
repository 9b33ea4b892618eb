"""Vectorized Levenberg-Marquardt for bundle adjustment on the reduced camera system (Schur complement).

Why a NumPy solver next to GTSAM: with ~15 000 reprojection factors GTSAM's Python-built graph spends
0.15-0.3 s per LM iteration here (per-factor linearization and elimination of 3 000 tiny point
cliques), so a BA takes > 1 s; this solver needs ~15 ms per iteration. Bundle adjustment has a fixed block structure that vectorizes: every
observation gives one ``3 x 6`` camera block and one ``3 x 3`` point block, the point blocks of the
Hessian are ``3 x 3`` diagonal blocks, and eliminating the points first (Schur complement) leaves a
small dense ``6K x 6K`` camera system (Triggs et al., "Bundle Adjustment - A Modern Synthesis",
2000, Sec. 6.1; Hartley & Zisserman A6.3). Per iteration:

    H = J^T W J,  g = J^T W r            (W = per-row information x robust IRLS weight)
    [U   Wc] [dc]   [gc]                 U: camera blocks, V: point blocks (block diagonal)
    [Wc^T V] [dp] = [gp]
    S = U - Wc V^-1 Wc^T,  S dc = gc - Wc V^-1 gp,  dp = V^-1 (gp - Wc^T dc)

with Marquardt damping ``diag(H) (1 + lambda)`` and Huber weights by iteratively reweighted least
squares (``w = 1`` for ``sqrt(chi2) <= k``, else ``k / sqrt(chi2)``; the cost is Huber's rho).

Parametrization: the solver works on ``T_cam_world = (R, t)``; a step ``delta = (rho, phi)`` updates
``R <- Exp(phi) R``, ``t <- Exp(phi) t + rho`` so that ``X_cam <- Exp(phi) X_cam + rho`` and
``d X_cam / d delta = [I, -[X_cam]_x]`` at ``delta = 0``. Measurements per observation are
``(u, v, u_right)`` with ``u = fx x/z + cx``, ``v = fy y/z + cy``, ``u_right = u - fx b / z``
(rectified stereo, or RGB-D with a virtual baseline); monocular rows carry zero weight on ``u_right``.

Implementation notes: the per-observation work (prediction, Jacobian products, point and camera
sums, the coupling blocks ``W_i``) is one compiled loop each (:mod:`vslam.backend.schur_kernels`,
numba); per-observation outputs are component-major ``(a, M)`` rows. The reduced camera system
``S = U - sum_p sum_{i,j in obs(p)} W_i V_p W_j^T`` is summed per point over its observation pairs
(local BA, 10 + 10 keyframes: ~30 000 pairs of 6 x 3 blocks, ~7x fewer multiply-adds than the dense
``6 n_c x 3 P`` GEMM it replaced, 2-3x faster than a BSR sparse product on global problems), then
solved densely (LAPACK Cholesky, ``O(n_c^3)``) up to ``sparse_min_cameras`` variable cameras (config
``backend.*.sparse_min_cameras``, 200); above, unless more than a quarter of the camera pairs share
points, the same sums go into the non-zero ``6 x 6`` blocks only and SuperLU solves them
(:mod:`vslam.backend.schur_sparse`; issue #26: 259 cameras along a trajectory, 7.5 vs 49 ms per
damped solve). BLAS is held to one thread during a solve
(threadpoolctl; process-wide while it runs): on a busy machine threaded GEMMs were 30x slower.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.linalg.lapack

from vslam.backend import schur_kernels, schur_sparse
from vslam.geometry.lie import so3_exp

try:  # BLAS threads on a busy 2-core machine make the 60 x 9000 GEMM 30x slower; one thread is best
    from threadpoolctl import ThreadpoolController
except ImportError:  # pragma: no cover - optional
    ThreadpoolController = None

LOG = logging.getLogger(__name__)


@dataclass
class Observations:
    """Resolved observations: camera/point row indices and measurements.

    ``meas (M, 3)`` holds ``(u, v, u_right)`` (``u_right`` 0 where mono), ``baseline (M,)`` the
    (virtual) stereo baseline per observation, ``stereo (M,)`` whether ``u_right`` is measured and
    ``info (M,)`` the information ``1 / sigma^2``. ``disparity (M,)`` (default all False) makes the
    third residual the disparity ``(u - u_right) - fx b / z`` instead of ``u_right - (u - fx b / z)``:
    independent errors on ``(u, v, disparity)`` rather than on ``(u, v, u_right)``.
    ``info_d (M,)`` (default ``info``) is the information of that third residual.
    """

    cam: np.ndarray
    pt: np.ndarray
    meas: np.ndarray
    baseline: np.ndarray
    stereo: np.ndarray
    info: np.ndarray
    disparity: np.ndarray | None = None
    info_d: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.meas_T = np.ascontiguousarray(self.meas.T)
        self.uniform_info = self.info_d is None  # the three rows share ``info`` (the exact original arithmetic)
        if self.info_d is None:
            self.info_d = self.info
        if self.disparity is None:
            self.disparity = np.zeros(len(self.cam), bool)
        self.any_disparity = bool(np.any(self.disparity))


@dataclass(frozen=True)
class Intrinsics:
    fx: float
    fy: float
    cx: float
    cy: float


_CONTROLLER = None
# Marquardt's damping policy (Marquardt 1963; Nocedal & Wright, Numerical Optimization, Sec. 10.3):
# a rejected step multiplies lambda by LAMBDA_FACTOR and retries, an accepted one divides it (not below
# LAMBDA_MIN); past LAMBDA_MAX the step is below rounding and the pass stops ("damping exhausted").
LAMBDA_FACTOR = 10.0
LAMBDA_MAX = 1e10
LAMBDA_MIN = 1e-12


def _blas_single_thread():
    """Context manager limiting BLAS to one thread (no-op without threadpoolctl)."""
    global _CONTROLLER
    if ThreadpoolController is None:
        import contextlib

        return contextlib.nullcontext()
    if _CONTROLLER is None:
        _CONTROLLER = ThreadpoolController()
    return _CONTROLLER.limit(limits=1, user_api="blas")


def _inv3(A: np.ndarray) -> np.ndarray:
    """Inverse of ``(3, 3, N)`` component-major matrices by the adjugate (vectorized over ``N``)."""
    a, b, c = A[0]
    d, e, f = A[1]
    g, h, i = A[2]
    co = np.empty_like(A)
    co[0, 0], co[0, 1], co[0, 2] = e * i - f * h, c * h - b * i, b * f - c * e
    co[1, 0], co[1, 1], co[1, 2] = f * g - d * i, a * i - c * g, c * d - a * f
    co[2, 0], co[2, 1], co[2, 2] = d * h - e * g, b * g - a * h, a * e - b * d
    co /= a * co[0, 0] + b * co[1, 0] + c * co[2, 0]
    return co


def _predict(R_cam_world, t_cam_world, X_world, obs, intr, min_depth):
    """Residuals ``r (3, M)`` (measurement minus prediction), ``chi2 (M,)`` and ``X_cam (3, M)``, all
    component-major so every row is a contiguous ``(M,)`` (compiled: :func:`schur_kernels.predict`).

    ``X_cam = R X_world + t``, ``u = fx x / z + cx``, ``v = fy y / z + cy``, third residual
    ``u_right - (u - fx b / z)`` (or the disparity ``(u - u_right) - fx b / z``), zero when mono;
    ``chi2 = info r^T r`` (``info_d`` on the third row when given), ``inf`` where ``z <= min_depth``.
    """
    m = len(obs.cam)
    r = np.empty((3, m))
    chi2 = np.empty(m)
    X_cam = np.empty((3, m))
    schur_kernels.predict(
        np.ascontiguousarray(R_cam_world, dtype=float), np.ascontiguousarray(t_cam_world, dtype=float),
        np.ascontiguousarray(X_world, dtype=float), obs.cam, obs.pt, obs.meas_T, obs.baseline, obs.stereo,
        obs.disparity, obs.any_disparity, obs.info, obs.info_d, obs.uniform_info, float(intr.fx), float(intr.fy),
        float(intr.cx), float(intr.cy), float(min_depth), r, chi2, X_cam,
    )
    return r, chi2, X_cam


def residuals(R_cam_world: np.ndarray, t_cam_world: np.ndarray, X_world: np.ndarray, obs: Observations,
              intr: Intrinsics, min_depth: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Measurement minus prediction ``r (M, 3)``, per-observation ``chi2 (M,)`` and ``X_cam (M, 3)``.

    Observations with the point closer than ``min_depth`` get ``chi2 = inf``.
    """
    r, chi2, X_cam = _predict(R_cam_world, t_cam_world, X_world, obs, intr, min_depth)
    return r.T, chi2, X_cam.T


def _robust_cost(chi2: np.ndarray, active: np.ndarray, huber: np.ndarray | None, prev: np.ndarray | None = None) -> float:
    """Sum over the ``active`` observations of ``chi2`` (Huber's ``rho`` of it when ``huber`` is given);
    a non-finite ``chi2`` counts 0, or ``1e6 + 10 prev`` when ``prev`` is given (a point pushed behind a
    camera must not look like a cost decrease). The terms come compacted from one compiled loop
    (:func:`schur_kernels.robust_terms`) and are summed by ``np.sum`` (pairwise, as before)."""
    out = np.empty(len(chi2))
    n = schur_kernels.robust_terms(chi2, chi2 if prev is None else prev, prev is not None, active,
                                   huber is not None, chi2 if huber is None else huber, out)
    return float(np.sum(out[:n]))


class _Structure:
    """Index patterns and buffers that stay fixed over the iterations (built once per solve).

    The coupling blocks ``Hcp (M, 3, 6)`` (``W_i^T``, one per observation, reused by every
    linearization) are reduced per point over the observation pairs of its variable cameras
    (:func:`schur_kernels.reduced_camera_system`): ``pt_obs[pt_ptr[p]:pt_ptr[p + 1]]`` are the
    observations of point ``p`` by variable cameras, in camera order, ``obs_var`` each observation's
    variable camera (``-1``: fixed).
    """

    def __init__(self, obs: Observations, cam_var: np.ndarray, n_var_cams: int, n_points: int,
                 sparse_min_cameras: int | None = None) -> None:
        self.n_c, self.n_p = n_var_cams, n_points
        self.obs_var = cam_var[obs.cam]
        free = np.flatnonzero(self.obs_var >= 0)
        pf = obs.pt[free]
        self.pt_ptr = np.zeros(n_points + 1, np.int64)
        np.cumsum(np.bincount(pf, minlength=n_points), out=self.pt_ptr[1:])
        # camera-sorted observations: each point's in camera order (any order is correct, this one is faster)
        self.pt_obs = np.empty(len(free), np.int64)
        schur_kernels.group_by_point(free, pf, self.pt_ptr, self.pt_obs)
        self.Hcp = np.empty((len(obs.cam), 3, 6) if n_var_cams > 0 else (0, 3, 6))
        self._Y = np.empty((int(np.diff(self.pt_ptr).max(initial=0)), 3, 6))
        self._bc = np.empty(6 * n_var_cams)
        # above sparse_min_cameras variable cameras, unless most camera pairs share points: the block-sparse S
        self.sparse = (schur_sparse.sparse_system(self.pt_ptr, self.pt_obs, self.obs_var, n_var_cams)
                       if sparse_min_cameras is not None and n_var_cams > sparse_min_cameras else None)
        self._S = np.empty((6 * n_var_cams, 6 * n_var_cams) if self.sparse is None else (0, 0))

    def reduce(self, W: np.ndarray, V: np.ndarray, gp: np.ndarray, gc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``S = -W blockdiag(V) W^T`` (dense ``6 n_c x 6 n_c``; overwritten by the next call) and
        ``bc = gc - W blockdiag(V) gp``, for the blocks ``W (M, 3, 6)`` and ``V (3, 3, P)``. On the sparse
        path ``S`` is left in ``self.sparse`` (its blocks) and the first item returned is None."""
        if self.sparse is not None:
            self.sparse.reduce(W, np.ascontiguousarray(V), gp, gc, self.pt_ptr, self.pt_obs, self.obs_var, self._Y,
                               self._bc)
            return None, self._bc
        schur_kernels.reduced_camera_system(W, np.ascontiguousarray(V), gp, gc, self.pt_ptr, self.pt_obs,
                                            self.obs_var, self._S, self._bc, self._Y)
        return self._S, self._bc

    def back_substitute(self, W: np.ndarray, V: np.ndarray, gp: np.ndarray, dc: np.ndarray) -> np.ndarray:
        """Point steps ``dp = blockdiag(V) (gp - W^T dc)`` as ``(3, P)``."""
        dp = np.empty((3, self.n_p))
        schur_kernels.back_substitute(W, np.ascontiguousarray(V), gp, np.ascontiguousarray(dc), self.pt_ptr,
                                      self.pt_obs, self.obs_var, dp)
        return dp


@dataclass
class LMResult:
    R_cam_world: np.ndarray
    t_cam_world: np.ndarray
    X_world: np.ndarray
    iterations: int
    initial_cost: float
    final_cost: float
    # residuals (M, 3) and chi2 (M,) at the returned estimate and at the start, in the caller's
    # observation order: what :func:`residuals` gives there, to the bit
    r: np.ndarray | None = None
    chi2: np.ndarray | None = None
    r_start: np.ndarray | None = None
    chi2_start: np.ndarray | None = None


class Prepared:
    """What :func:`solve` derives from the observations and the camera variables alone, built once
    for the passes of one bundle adjustment (:func:`prepare`): the camera-sorted observations (the
    caller's when already sorted, the usual case), their order, the :class:`_Structure`, and the
    residuals at the last estimate a solve returned (the next pass starts there)."""

    def __init__(self, obs: Observations, cam_var: np.ndarray, n_points: int,
                 sparse_min_cameras: int | None = None) -> None:
        cam = obs.cam
        self.order = None if np.all(cam[1:] >= cam[:-1]) else np.argsort(cam, kind="stable")
        if self.order is not None:  # camera-sorted: locality, pairs in camera order
            o = self.order
            obs = Observations(obs.cam[o], obs.pt[o], obs.meas[o], obs.baseline[o], obs.stereo[o], obs.info[o],
                               obs.disparity[o], None if obs.uniform_info else obs.info_d[o])
        self.obs = obs
        self.cam_var = cam_var
        self.n_points = n_points
        self.var_rows = np.flatnonzero(cam_var >= 0)
        self.st = _Structure(obs, cam_var, int(cam_var.max(initial=-1)) + 1, n_points, sparse_min_cameras)
        self.last: tuple | None = None  # (R, t, X, r, chi2, X_cam) of the last returned estimate (sorted order)

    def sorted_(self, a: np.ndarray | None) -> np.ndarray | None:
        """``a`` (per observation, caller's order) in the solver's order."""
        return a if a is None or self.order is None else a[self.order]

    def unsorted(self, r: np.ndarray, chi2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``r (3, M)``, ``chi2 (M,)`` back in the caller's order, as :func:`residuals` returns them."""
        if self.order is None:
            return r.T, chi2
        r_out, chi2_out = np.empty_like(r), np.empty_like(chi2)
        r_out[:, self.order] = r
        chi2_out[self.order] = chi2
        return r_out.T, chi2_out


def prepare(obs: Observations, cam_var: np.ndarray, n_points: int, sparse_min_cameras: int | None = None) -> Prepared:
    """The per-problem setup of :func:`solve`, to share between its passes. Above ``sparse_min_cameras``
    variable cameras the reduced camera system is block-sparse (:mod:`vslam.backend.schur_sparse`;
    None: always dense)."""
    return Prepared(obs, cam_var, n_points, sparse_min_cameras)


def _linearize(R, X_cam, r, chi2, w_rows, huber, obs, intr, st):
    """Gauss-Newton blocks ``Hcc (n_c,6,6), gc (6 n_c,), W, Hpp (3,3,P), gp (3,P)``.

    With ``Jh = d(u, v, u_r)/d X_cam``, ``A = Jh^T W Jh`` and ``b = Jh^T W r`` per observation, the point
    Jacobian is ``Jh R`` and the camera Jacobian ``Jh G`` with ``G = [I, -[X_cam]_x]``, so
    ``Hpp = R^T A R``, ``Hcp = G^T A R = [A R; [X]_x A R]``, ``Hcc = [[A, C^T], [C, -C [X]_x]]`` with
    ``C = [X]_x A``, ``gp = R^T b`` and ``gc = [b; X x b]`` (``Jh`` has six non-zeros, written out).
    The per-observation products, the point sums and the camera sums (``(n_c, 33)``) are one
    compiled loop (:func:`schur_kernels.linearize`); no ``(M, 6, 6)`` stacked matmuls.
    """
    Hpp = np.empty((3, 3, st.n_p))
    gp = np.empty((3, st.n_p))
    sums = np.empty((st.n_c, 33))  # A (9), C = [X]_x A (9), -C [X]_x (9), g (6) summed per camera
    schur_kernels.linearize(
        np.ascontiguousarray(R, dtype=float), obs.cam, obs.pt, X_cam, r, chi2, w_rows, huber is not None,
        huber if huber is not None else chi2, obs.baseline, obs.disparity, obs.any_disparity, float(intr.fx),
        float(intr.fy), st.obs_var, st.Hcp, sums, Hpp, gp,
    )
    if st.n_c == 0:
        return None, None, None, Hpp, gp
    Hcc = np.empty((st.n_c, 6, 6))
    Hcc[:, :3, :3] = sums[:, :9].reshape(-1, 3, 3)
    Hcc[:, 3:, :3] = sums[:, 9:18].reshape(-1, 3, 3)
    Hcc[:, :3, 3:] = np.transpose(Hcc[:, 3:, :3], (0, 2, 1))
    Hcc[:, 3:, 3:] = sums[:, 18:27].reshape(-1, 3, 3)
    gc = sums[:, 27:33].reshape(-1)
    return Hcc, gc, st.Hcp, Hpp, gp


def _solve_damped(Hcc, gc, W, Hpp, gp, lam, st):
    """Solve the Marquardt-damped normal equations by the Schur complement on the cameras.

    Returns ``dc (n_c, 6)`` and ``dp (3, P)``.
    """
    n_c = st.n_c
    # Marquardt damping plus an isotropic share (1 % of the mean diagonal): a monocular point seen once
    # (or with tiny parallax) has a near-null depth direction that diag(H) alone would leave undamped;
    # the damped blocks inverted by the adjugate (as _inv3) in one compiled loop
    V = np.empty_like(Hpp)
    schur_kernels.damped_point_inverse(Hpp, float(lam), V)
    if n_c == 0:
        return np.zeros((0, 6)), np.einsum("ijp,jp->ip", V, gp)
    S, bc = st.reduce(W, V, gp, gc)
    if st.sparse is not None:  # the same S, block-sparse, factored by SuperLU
        dc = st.sparse.solve(Hcc, lam, bc)
    else:
        schur_kernels.add_damped_camera_blocks(S, Hcc, float(lam))  # S += blockdiag(Hcc damped)
        _, dc, info = scipy.linalg.lapack.dposv(S, bc)  # Cholesky on the upper triangle (no condition estimate)
        if info != 0:  # not positive definite (or invalid input)
            dc = np.linalg.lstsq(S, bc, rcond=None)[0]
    dp = st.back_substitute(W, V, gp, dc)
    return dc.reshape(-1, 6), dp


def solve(R_cam_world: np.ndarray, t_cam_world: np.ndarray, X_world: np.ndarray, cam_var: np.ndarray,
          obs: Observations, intr: Intrinsics, active: np.ndarray, huber: np.ndarray | None,
          max_iterations: int, lambda_initial: float = 1e-4, relative_tolerance: float = 1e-7,
          min_depth: float = 1e-3, prepared: Prepared | None = None) -> LMResult:
    """Run LM on cameras with ``cam_var >= 0`` (their variable index) and all points.

    ``active (M,)`` selects the observations used; ``huber (M,)`` the per-observation Huber threshold
    on ``sqrt(chi2)`` (``None``: plain least squares). Cameras with ``cam_var < 0`` stay fixed.
    ``prepared``: :func:`prepare` of the same ``obs`` and ``cam_var`` (built here when None); a solve
    starting at the estimate the previous one returned (the same arrays) reuses its residuals.
    """
    if prepared is None:
        prepared = Prepared(obs, cam_var, len(X_world))
    elif prepared.n_points != len(X_world) or len(prepared.obs.cam) != len(obs.cam):
        raise ValueError("schur_lm.solve: `prepared` was built for another problem")
    with _blas_single_thread():
        return _solve(R_cam_world, t_cam_world, X_world, prepared, intr, prepared.sorted_(active),
                      prepared.sorted_(huber), max_iterations, lambda_initial, relative_tolerance, min_depth)


def _step(R, t, X, dc, dp, pr):
    """``R <- Exp(phi) R``, ``t <- Exp(phi) t + rho`` for the variable cameras, ``X <- X + dp``."""
    var_rows, cam_var = pr.var_rows, pr.cam_var
    R_new, t_new = R.copy(), t.copy()
    dR = so3_exp(dc[cam_var[var_rows], 3:])
    R_new[var_rows] = dR @ R[var_rows]
    t_new[var_rows] = np.einsum("kij,kj->ki", dR, t[var_rows]) + dc[cam_var[var_rows], :3]
    return R_new, t_new, X + dp.T


def _solve(R_in, t_in, X_in, pr, intr, active, huber, max_iterations, lambda_initial, relative_tolerance, min_depth):
    obs, st = pr.obs, pr.st
    last = pr.last
    if last is not None and last[0] is R_in and last[1] is t_in and last[2] is X_in:
        R, t, X, r, chi2, X_cam = last
    else:
        R, t, X = R_in.copy(), t_in.copy(), X_in.copy()
        r, chi2, X_cam = _predict(R, t, X, obs, intr, min_depth)
    act = active.astype(float) * obs.info
    w_rows = np.stack([act, act, act * obs.stereo if obs.uniform_info else active * obs.info_d * obs.stereo])
    lam = lambda_initial
    start = pr.unsorted(r, chi2)
    cost = _robust_cost(chi2, active, huber)
    initial_cost = cost
    iterations = 0
    for _ in range(max_iterations):
        iterations += 1
        Hcc, gc, W, Hpp, gp = _linearize(R, X_cam, r, chi2, w_rows, huber, obs, intr, st)
        while True:
            dc, dp = _solve_damped(Hcc, gc, W, Hpp, gp, lam, st)
            R_new, t_new, X_new = _step(R, t, X, dc, dp, pr)
            r_new, chi2_new, X_cam_new = _predict(R_new, t_new, X_new, obs, intr, min_depth)
            new_cost = _robust_cost(chi2_new, active, huber, prev=chi2)
            if new_cost < cost:
                break
            lam *= LAMBDA_FACTOR
            if lam > LAMBDA_MAX:
                LOG.debug("LM: damping exhausted after %d iterations (cost %.6g)", iterations, cost)
                return _result(pr, R, t, X, r, chi2, X_cam, iterations, initial_cost, cost, start)
        decrease = cost - new_cost
        LOG.debug("LM iteration %d: cost %.6g -> %.6g (lambda %.1e)", iterations, cost, new_cost, lam)
        R, t, X, r, chi2, X_cam, cost = R_new, t_new, X_new, r_new, chi2_new, X_cam_new, new_cost
        lam = max(lam / LAMBDA_FACTOR, LAMBDA_MIN)
        if decrease <= relative_tolerance * max(cost + decrease, 1e-12):
            break
    return _result(pr, R, t, X, r, chi2, X_cam, iterations, initial_cost, cost, start)


def _result(pr, R, t, X, r, chi2, X_cam, iterations, initial_cost, cost, start) -> LMResult:
    pr.last = (R, t, X, r, chi2, X_cam)
    r_out, chi2_out = pr.unsorted(r, chi2)
    return LMResult(R, t, X, iterations, initial_cost, cost, r_out, chi2_out, start[0], start[1])
