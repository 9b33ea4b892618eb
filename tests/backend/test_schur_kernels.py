"""The compiled Gauss-Newton blocks of vslam.backend.schur_kernels against numerical Jacobians."""
from __future__ import annotations

import numpy as np
import pytest

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
    W_ref = np.zeros((6 * n_c, 3 * P))
    for m in np.flatnonzero(var >= 0):
        c, p = var[m], obs.pt[m]
        Hcc_ref[c] += J_cam[m].T @ (Wm[m][:, None] * J_cam[m])
        W_ref[6 * c:6 * c + 6, [p, P + p, 2 * P + p]] = J_cam[m].T @ (Wm[m][:, None] * J_pt[m])
    np.testing.assert_allclose(Hcc, Hcc_ref, atol=1e-5 * np.abs(Hcc_ref).max())
    np.testing.assert_allclose(W, W_ref, atol=1e-5 * np.abs(W_ref).max())
    # W blockdiag(V) at the observed blocks equals the dense product
    V = np.random.default_rng(0).normal(size=(3, 3, P))
    Y_ref = np.einsum("ajp,jkp->akp", W.reshape(6 * n_c, 3, P), V).reshape(W.shape)
    np.testing.assert_array_equal(st.times_blockdiag(W, V), Y_ref)
