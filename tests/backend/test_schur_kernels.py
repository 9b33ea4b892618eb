"""The compiled Gauss-Newton blocks of vslam.backend.schur_kernels against numerical Jacobians."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg

from vslam.backend import schur_lm
from vslam.backend.bundle_adjustment import _cam_var, _observations, _split_poses
from vslam.backend.config import LocalBAConfig
from vslam.backend.synthetic import make_ba_problem
from vslam.geometry.lie import so3_exp


def _camera_sorted(obs):
    """The observations in camera order (stable), as the solver takes them."""
    order = np.argsort(obs.cam, kind="stable")
    return schur_lm.Observations(obs.cam[order], obs.pt[order], obs.meas[order], obs.baseline[order],
                                 obs.stereo[order], obs.info[order], obs.disparity[order], None)


@pytest.mark.parametrize("sensor", ["mono", "stereo", "rgbd"])
def test_linearized_blocks_equal_numerical_jacobians(sensor):
    problem, _ = make_ba_problem(n_keyframes=4, n_points=30, sensor=sensor, seed=3)
    obs = _observations(problem, LocalBAConfig())
    obs = _camera_sorted(obs)
    intr = schur_lm.Intrinsics(problem.camera.fx, problem.camera.fy, problem.camera.cx, problem.camera.cy)
    cam_var = _cam_var(problem, problem.fixed_kf_ids)
    R, t = _split_poses(problem.T_world_cam)
    X = problem.X_world
    n_c, P, M = int(cam_var.max()) + 1, len(X), len(obs.cam)
    st = schur_lm._Structure(obs, cam_var, n_c, P)
    r, chi2, X_cam = schur_lm._predict(R, t, X, obs, intr, 1e-3)
    w_rows = np.stack([obs.info, obs.info, obs.info * obs.stereo])
    Hcc, gc, W, Hpp, gp = schur_lm._linearize(R, X_cam, r, chi2, w_rows, None, obs, intr, st)

    # numerical d r / d (camera delta, point) by central differences of the residuals
    eps = 1e-6
    J_cam = np.zeros((M, 3, 6))
    for k in range(6):
        d = np.zeros(6)
        d[k] = eps
        rs = []
        for s in (1, -1):
            dR = so3_exp(s * d[3:])
            Rn = np.einsum("ij,kjl->kil", dR, R)
            tn = t @ dR.T + s * d[:3]
            rs.append(schur_lm.residuals(Rn, tn, X, obs, intr, 1e-3)[0])
        J_cam[:, :, k] = -(rs[0] - rs[1]) / (2 * eps)  # residual = measurement - prediction
    J_pt = np.zeros((M, 3, 3))
    for k in range(3):
        rs = []
        for s in (1, -1):
            Xn = X.copy()
            Xn[:, k] += s * eps
            rs.append(schur_lm.residuals(R, t, Xn, obs, intr, 1e-3)[0])
        J_pt[:, :, k] = -(rs[0] - rs[1]) / (2 * eps)
    Wm = w_rows.T  # (M, 3) per-row weights
    Hpp_ref = np.zeros((P, 3, 3))
    np.add.at(Hpp_ref, obs.pt, np.einsum("mai,ma,maj->mij", J_pt, Wm, J_pt))
    gp_ref = np.zeros((P, 3))
    np.add.at(gp_ref, obs.pt, np.einsum("mai,ma,ma->mi", J_pt, Wm, r.T))
    scale = np.abs(Hpp_ref).max()
    np.testing.assert_allclose(Hpp.transpose(2, 0, 1), Hpp_ref, atol=1e-5 * scale)
    np.testing.assert_allclose(gp.T, gp_ref, atol=1e-5 * np.abs(gp_ref).max())
    var = cam_var[obs.cam]
    Hcc_ref = np.zeros((n_c, 6, 6))
    W_ref = np.zeros((M, 6, 3))
    for m in np.flatnonzero(var >= 0):
        c = var[m]
        Hcc_ref[c] += J_cam[m].T @ (Wm[m][:, None] * J_cam[m])
        W_ref[m] = J_cam[m].T @ (Wm[m][:, None] * J_pt[m])
    free = var >= 0
    np.testing.assert_allclose(Hcc, Hcc_ref, atol=1e-5 * np.abs(Hcc_ref).max())
    np.testing.assert_allclose(W.transpose(0, 2, 1)[free], W_ref[free], atol=1e-5 * np.abs(W_ref).max())


def _dense_coupling(W, obs, cam_var, n_c, P):
    """The dense ``W (6 n_c, 3 P)`` (columns ``3 p + j``) from the per-observation blocks ``W (M, 3, 6)``."""
    Wd = np.zeros((6 * n_c, 3 * P))
    var = cam_var[obs.cam]
    for m in np.flatnonzero(var >= 0):
        Wd[6 * var[m]:6 * var[m] + 6, 3 * obs.pt[m]:3 * obs.pt[m] + 3] += W[m].T
    return Wd


@pytest.mark.parametrize("sensor", ["mono", "rgbd"])
def test_pointwise_schur_complement_equals_the_dense_reference(sensor):
    """S = U - W blockdiag(V) W^T, bc and the back-substitution, summed per point over observation
    pairs, against dense matrices; one camera seeing a point twice is included (blocks B + B^T)."""
    problem, _ = make_ba_problem(n_keyframes=6, n_points=80, sensor=sensor, n_fixed=2, seed=11)
    obs = _observations(problem, LocalBAConfig())
    dup = np.flatnonzero(obs.cam == obs.cam.max())[:5]  # a camera observing five points a second time
    assert _cam_var(problem, problem.fixed_kf_ids)[obs.cam.max()] >= 0  # ... and a variable one
    obs = schur_lm.Observations(*(np.concatenate([a, a[dup]]) for a in (
        obs.cam, obs.pt, obs.meas, obs.baseline, obs.stereo, obs.info, obs.disparity)), None)
    obs = _camera_sorted(obs)
    intr = schur_lm.Intrinsics(problem.camera.fx, problem.camera.fy, problem.camera.cx, problem.camera.cy)
    cam_var = _cam_var(problem, problem.fixed_kf_ids)
    R, t = _split_poses(problem.T_world_cam)
    X = problem.X_world + np.random.default_rng(1).normal(scale=0.01, size=problem.X_world.shape)
    n_c, P = int(cam_var.max()) + 1, len(X)
    st = schur_lm._Structure(obs, cam_var, n_c, P)
    r, chi2, X_cam = schur_lm._predict(R, t, X, obs, intr, 1e-3)
    w_rows = np.stack([obs.info, obs.info, obs.info * obs.stereo])
    Hcc, gc, W, Hpp, gp = schur_lm._linearize(R, X_cam, r, chi2, w_rows, np.full(len(chi2), 2.0), obs, intr, st)
    V = schur_lm._inv3(Hpp + 0.1 * np.eye(3)[:, :, None])
    S, bc = st.reduce(W, V, gp, gc)
    S, bc = S.copy(), bc.copy()
    Wd = _dense_coupling(W, obs, cam_var, n_c, P)
    Vd = scipy.linalg.block_diag(*V.transpose(2, 0, 1))
    gpd = gp.T.reshape(-1)
    S_ref = -Wd @ Vd @ Wd.T
    np.testing.assert_allclose(S, S_ref, rtol=0, atol=1e-9 * np.abs(S_ref).max())
    np.testing.assert_allclose(bc, gc - Wd @ Vd @ gpd, rtol=0, atol=1e-9 * np.abs(bc).max())
    dc = np.random.default_rng(2).normal(size=6 * n_c)
    dp_ref = (Vd @ (gpd - Wd.T @ dc)).reshape(-1, 3).T
    np.testing.assert_allclose(st.back_substitute(W, V, gp, dc), dp_ref, rtol=0, atol=1e-9 * np.abs(dp_ref).max())


def test_warm_compiles_the_signatures_the_solver_calls():
    """After ``warm()`` a real solve (RGB-D with disparity rows, Huber then plain) adds no signature:
    its first call paid no compilation."""
    from vslam.backend import schur_kernels
    from vslam.backend.bundle_adjustment import local_bundle_adjustment

    schur_kernels.warm()
    kernels = (schur_kernels.predict, schur_kernels.linearize, schur_kernels.reduced_camera_system,
               schur_kernels.back_substitute, schur_kernels.group_by_point, schur_kernels.robust_terms,
               schur_kernels.damped_point_inverse, schur_kernels.add_damped_camera_blocks)
    assert [len(k.signatures) for k in kernels] == [1] * 8
    problem, _ = make_ba_problem(n_keyframes=4, n_points=40, sensor="rgbd", seed=2)
    local_bundle_adjustment(problem)
    assert [len(k.signatures) for k in kernels] == [1] * 8


def test_group_by_point_is_the_stable_argsort():
    from vslam.backend import schur_kernels

    rng = np.random.default_rng(5)
    pf = rng.integers(0, 50, 400)
    free = np.sort(rng.choice(1000, 400, replace=False))
    ptr = np.zeros(51, np.int64)
    np.cumsum(np.bincount(pf, minlength=50), out=ptr[1:])
    out = np.empty(400, np.int64)
    schur_kernels.group_by_point(free, pf, ptr, out)
    np.testing.assert_array_equal(out, free[np.argsort(pf, kind="stable")])


def test_robust_cost_is_the_numpy_expression_to_the_bit():
    """Huber / plain, with points behind the camera (inf) counted 0 or 1e6 + 10 chi2_before."""
    rng = np.random.default_rng(6)
    chi2 = rng.exponential(4.0, 3000)
    chi2[rng.choice(3000, 40, replace=False)] = np.inf
    prev = rng.exponential(4.0, 3000)
    prev[:20] = np.inf
    chi2[:20] = np.inf  # both infinite: 1e6 + 0
    active = rng.random(3000) < 0.9
    huber = np.where(rng.random(3000) < 0.5, np.sqrt(5.991), np.sqrt(7.815))
    for k in (huber, None):
        c = np.where(np.isfinite(chi2), chi2, 0.0)
        c_eval = np.where(np.isfinite(chi2), chi2, 1e6 + 10.0 * np.where(np.isfinite(prev), prev, 0.0))
        costs = []
        for cc, p in ((c, None), (c_eval, prev)):
            a = cc[active]
            ref = float(np.sum(a)) if k is None else float(np.sum(np.where(np.sqrt(a) <= k[active], a, 2.0 * k[active] * np.sqrt(a) - k[active] * k[active])))
            got = schur_lm._robust_cost(chi2, active, k, prev=p)
            assert got == ref
            costs.append(got)
        assert costs[1] > costs[0] + 20 * (1e6 if k is None else 2 * np.sqrt(5.991) * 999)


def test_damped_point_inverse_is_the_numpy_expression_to_the_bit():
    from vslam.backend import schur_kernels

    rng = np.random.default_rng(7)
    J = rng.normal(size=(200, 4, 3))
    Hpp = np.ascontiguousarray(np.einsum("pki,pkj->ijp", J, J))
    Hpp[:, :, 0] = 0.0  # an unobserved point: floored diagonal
    for lam in (1e-4, 3.7, 1e3):
        Hd = Hpp.copy()
        iso = 0.01 * (Hpp[0, 0] + Hpp[1, 1] + Hpp[2, 2]) / 3.0
        for i in range(3):
            Hd[i, i] += lam * (np.maximum(Hpp[i, i], 1e-9) + iso)
        V = np.empty_like(Hpp)
        schur_kernels.damped_point_inverse(Hpp, lam, V)
        np.testing.assert_array_equal(V, schur_lm._inv3(Hd))


def test_prepared_solve_on_unsorted_observations_equals_the_sorted_one():
    """Observations out of camera order are sorted once (``prepare``); the returned residuals are in
    the caller's order and equal :func:`schur_lm.residuals` there; a second pass reusing them gives
    the result of a fresh solve, to the bit."""
    problem, _ = make_ba_problem(n_keyframes=5, n_points=60, sensor="rgbd", seed=4, noise_px=1.0)
    obs = _observations(problem, LocalBAConfig())
    perm = np.random.default_rng(3).permutation(len(obs.cam))
    obs_u = schur_lm.Observations(obs.cam[perm], obs.pt[perm], obs.meas[perm], obs.baseline[perm],
                                  obs.stereo[perm], obs.info[perm], obs.disparity[perm], obs.info_d[perm])
    intr = schur_lm.Intrinsics(problem.camera.fx, problem.camera.fy, problem.camera.cx, problem.camera.cy)
    cam_var = _cam_var(problem, problem.fixed_kf_ids)
    R, t = _split_poses(problem.T_world_cam)
    X = problem.X_world
    huber = np.full(len(perm), 2.0)
    active = np.ones(len(perm), bool)
    ref = schur_lm.solve(R, t, X, cam_var, obs, intr, active, huber, 5)
    pr = schur_lm.prepare(obs_u, cam_var, len(X))
    assert pr.order is not None and schur_lm.prepare(obs, cam_var, len(X)).order is None
    got = schur_lm.solve(R, t, X, cam_var, obs_u, intr, active, huber, 5, prepared=pr)
    # within a camera the observations keep the caller's order: sums in another order, ~1e-15 apart
    np.testing.assert_allclose(got.R_cam_world, ref.R_cam_world, rtol=0, atol=1e-12)
    np.testing.assert_allclose(got.X_world, ref.X_world, rtol=0, atol=1e-9)
    r, chi2, _ = schur_lm.residuals(got.R_cam_world, got.t_cam_world, got.X_world, obs_u, intr, 1e-3)
    np.testing.assert_array_equal(got.r, r)
    np.testing.assert_array_equal(got.chi2, chi2)
    np.testing.assert_allclose(got.chi2[np.argsort(perm)], ref.chi2, rtol=1e-6, atol=1e-9)
    again = schur_lm.solve(got.R_cam_world, got.t_cam_world, got.X_world, cam_var, obs_u, intr, chi2 < 7.8, None, 3,
                           prepared=pr)
    fresh = schur_lm.solve(got.R_cam_world.copy(), got.t_cam_world, got.X_world, cam_var, obs_u, intr, chi2 < 7.8,
                           None, 3)
    assert again.iterations == fresh.iterations >= 1
    np.testing.assert_array_equal(again.X_world, fresh.X_world)
    np.testing.assert_array_equal(again.r_start, got.r)


def test_damped_camera_blocks_are_the_numpy_expression_to_the_bit():
    from vslam.backend import schur_kernels

    rng = np.random.default_rng(8)
    J = rng.normal(size=(4, 9, 6))
    Hcc = np.einsum("kai,kaj->kij", J, J)
    Hcc[1, 2, 2] = 0.0  # a floored diagonal
    S0 = rng.normal(size=(24, 24))
    lam = 0.37
    ref = S0.copy()
    Hcc_d = Hcc.copy()
    Hcc_d[:, range(6), range(6)] += lam * np.maximum(np.einsum("kii->ki", Hcc), 1e-9)
    idx = np.arange(4)
    ref.reshape(4, 6, 4, 6)[idx, :, idx, :] += Hcc_d
    got = S0.copy()
    schur_kernels.add_damped_camera_blocks(got, Hcc, lam)
    np.testing.assert_array_equal(got, ref)


def _reduced_camera_system_before(Hcp, V, gp, gc, pt_ptr, pt_obs, obs_var, S, bc, Y):
    """The kernel as it was before its coupling entries were hoisted (plain Python, the same
    operations in the same order): the reference of the bit-identity test below."""
    S[:, :] = 0.0
    bc[:] = gc
    for p in range(len(pt_ptr) - 1):
        q0, k = pt_ptr[p], pt_ptr[p + 1] - pt_ptr[p]
        g0, g1, g2 = gp[0, p], gp[1, p], gp[2, p]
        for a in range(k):
            m = pt_obs[q0 + a]
            r6 = 6 * obs_var[m]
            for l in range(3):
                v0, v1, v2 = V[0, l, p], V[1, l, p], V[2, l, p]
                for i in range(6):
                    Y[a, l, i] = Hcp[m, 0, i] * v0 + Hcp[m, 1, i] * v1 + Hcp[m, 2, i] * v2
            for i in range(6):
                bc[r6 + i] -= Y[a, 0, i] * g0 + Y[a, 1, i] * g1 + Y[a, 2, i] * g2
        for a in range(k):
            ra = 6 * obs_var[pt_obs[q0 + a]]
            for b in range(a, k):
                mb = pt_obs[q0 + b]
                rb = 6 * obs_var[mb]
                for i in range(6):
                    for j in range(6):
                        s = Y[a, 0, i] * Hcp[mb, 0, j] + Y[a, 1, i] * Hcp[mb, 1, j] + Y[a, 2, i] * Hcp[mb, 2, j]
                        if ra < rb or b == a:
                            S[ra + i, rb + j] -= s
                        else:
                            S[rb + j, ra + i] -= s
                            if ra == rb:
                                S[ra + i, rb + j] -= s
    n = S.shape[0]
    for r in range(0, n, 6):
        for c in range(r + 6, n, 6):
            S[c:c + 6, r:r + 6] = S[r:r + 6, c:c + 6].T


@pytest.mark.parametrize("shuffle", [False, True])
def test_reduced_camera_system_equals_the_previous_kernel_to_the_bit(shuffle):
    """The compiled reduction (coupling entries hoisted per pair) gives the same ``S`` and ``bc``, to
    the bit, as the per-product loop it replaced; also with observations out of camera order (the
    transposed branch)."""
    from vslam.backend import schur_kernels

    rng = np.random.default_rng(11)
    n_c, P = 5, 40
    pt_ptr = np.zeros(P + 1, np.int64)
    obs_var, pt_obs = [], []
    for p in range(P):
        cams = rng.choice(n_c + 1, size=rng.integers(1, 5), replace=False) - 1  # -1: a fixed camera
        cams = cams[cams >= 0]
        if shuffle:
            rng.shuffle(cams)
        for c in cams:
            pt_obs.append(len(obs_var))
            obs_var.append(c)
        pt_ptr[p + 1] = len(obs_var)
    obs_var, pt_obs = np.array(obs_var, np.int64), np.array(pt_obs, np.int64)
    M = len(obs_var)
    Hcp = rng.normal(size=(M, 3, 6))
    V = rng.normal(size=(3, 3, P))
    V = np.ascontiguousarray(V + V.transpose(1, 0, 2))
    gp, gc = rng.normal(size=(3, P)), rng.normal(size=6 * n_c)
    Y = np.empty((4, 3, 6))
    S, bc = np.full((6 * n_c, 6 * n_c), np.nan), np.empty(6 * n_c)
    schur_kernels.reduced_camera_system(Hcp, V, gp, gc, pt_ptr, pt_obs, obs_var, S, bc, Y)
    S_ref, bc_ref = np.empty_like(S), np.empty_like(bc)
    _reduced_camera_system_before(Hcp, V, gp, gc, pt_ptr, pt_obs, obs_var, S_ref, bc_ref, np.empty_like(Y))
    assert np.abs(S_ref).max() > 1.0
    assert np.array_equal(S, S_ref) and np.array_equal(bc, bc_ref)
