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


@pytest.mark.parametrize("sensor", ["mono", "stereo", "rgbd"])
def test_linearized_blocks_equal_numerical_jacobians(sensor):
    problem, _ = make_ba_problem(n_keyframes=4, n_points=30, sensor=sensor, seed=3)
    obs = _observations(problem, LocalBAConfig())
    order = np.argsort(obs.cam, kind="stable")
    obs = schur_lm.Observations(obs.cam[order], obs.pt[order], obs.meas[order], obs.baseline[order],
                                obs.stereo[order], obs.info[order], obs.disparity[order], None)
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
    order = np.argsort(obs.cam, kind="stable")
    obs = schur_lm.Observations(obs.cam[order], obs.pt[order], obs.meas[order], obs.baseline[order],
                                obs.stereo[order], obs.info[order], obs.disparity[order], None)
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
               schur_kernels.back_substitute)
    assert [len(k.signatures) for k in kernels] == [1, 1, 1, 1]
    problem, _ = make_ba_problem(n_keyframes=4, n_points=40, sensor="rgbd", seed=2)
    local_bundle_adjustment(problem)
    assert [len(k.signatures) for k in kernels] == [1, 1, 1, 1]
