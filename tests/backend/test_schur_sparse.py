"""The block-sparse reduced camera system (vslam.backend.schur_sparse) against the dense one (issue #26)."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from vslam.backend import schur_lm, schur_sparse
from vslam.backend.bundle_adjustment import _cam_var, _observations, _split_poses, global_bundle_adjustment
from vslam.backend.config import GlobalBAConfig, LocalBAConfig
from vslam.backend.synthetic import make_ba_problem


def _linearized(problem, sparse_min_cameras):
    """The prepared problem and its Gauss-Newton blocks at the initial estimate (plain least squares)."""
    obs = _observations(problem, LocalBAConfig())
    intr = schur_lm.Intrinsics(problem.camera.fx, problem.camera.fy, problem.camera.cx, problem.camera.cy)
    pr = schur_lm.prepare(obs, _cam_var(problem, problem.fixed_kf_ids), len(problem.X_world), sparse_min_cameras)
    R, t = _split_poses(problem.T_world_cam)
    r, chi2, X_cam = schur_lm._predict(R, t, problem.X_world, pr.obs, intr, 1e-3)
    w_rows = np.stack([pr.obs.info, pr.obs.info, pr.obs.info * pr.obs.stereo])
    return pr, schur_lm._linearize(R, X_cam, r, chi2, w_rows, None, pr.obs, intr, pr.st)


def test_sparse_system_equals_dense_and_gives_the_same_step():
    # 60 keyframes along a line, each point seen by ~5 consecutive ones: 15 % of the camera blocks non-zero
    problem, _ = make_ba_problem(n_keyframes=60, n_points=1500, sensor="stereo", seed=1)
    pr_d, blocks_d = _linearized(problem, None)
    pr_s, blocks_s = _linearized(problem, 0)
    assert pr_d.st.sparse is None and pr_s.st.sparse is not None
    sp = pr_s.st.sparse
    assert 0.05 < sp.density < 0.25, sp.density
    Hcc, gc, W, Hpp, gp = blocks_d
    V = np.empty_like(Hpp)
    schur_lm.schur_kernels.damped_point_inverse(Hpp, 1e-4, V)
    S, bc_d = pr_d.st.reduce(W, V, gp, gc)
    S, bc_d = S.copy(), bc_d.copy()
    _, bc_s = pr_s.st.reduce(blocks_s[2], V, blocks_s[4], blocks_s[1])
    # the stored blocks are S's (the same terms in the same order: equal to rounding at most)
    S_sparse = np.zeros_like(S)
    for r in range(sp.n_c):
        for k in range(sp.row_ptr[r], sp.row_ptr[r + 1]):
            c = sp.cols[k]
            S_sparse[6 * r:6 * r + 6, 6 * c:6 * c + 6] = sp.B[k]
            S_sparse[6 * c:6 * c + 6, 6 * r:6 * r + 6] = sp.B[k].T
    scale = np.abs(S).max()
    assert np.abs(S_sparse - S).max() <= 1e-12 * scale
    assert np.abs(bc_s - bc_d).max() <= 1e-12 * np.abs(bc_d).max()
    # every block the dense S holds is in the pattern (zero blocks outside it)
    blk = np.abs(S).reshape(sp.n_c, 6, sp.n_c, 6).max(axis=(1, 3)) > 0
    assert np.array_equal(blk, np.abs(S_sparse).reshape(sp.n_c, 6, sp.n_c, 6).max(axis=(1, 3)) > 0)
    # the damped step: dense Cholesky vs SuperLU, measured 1e-13 relative (x86-64); 1e-8 is the bound
    for lam in (1e-4, 1e2):
        dc_d, dp_d = schur_lm._solve_damped(*blocks_d, lam, pr_d.st)
        dc_s, dp_s = schur_lm._solve_damped(*blocks_s, lam, pr_s.st)
        assert np.abs(dc_s - dc_d).max() <= 1e-8 * np.abs(dc_d).max()
        assert np.abs(dp_s - dp_d).max() <= 1e-8 * np.abs(dp_d).max()


def test_dense_pattern_stays_dense_and_threshold_is_exclusive():
    problem, _ = make_ba_problem(n_keyframes=12, n_points=400, sensor="rgbd", seed=4)
    assert _linearized(problem, 11)[0].st.sparse is None  # 11 variable cameras: not above 11
    pr = _linearized(problem, 10)[0]
    # 12 keyframes, points seen by ~5 of them: about half the blocks, above MAX_DENSITY: dense after all
    assert pr.st.sparse is None
    st = pr.st
    sp = schur_sparse.sparse_system(st.pt_ptr, st.pt_obs, st.obs_var, st.n_c, max_density=1.0)
    assert sp is not None and sp.density > schur_sparse.MAX_DENSITY
    assert LocalBAConfig().sparse_min_cameras >= 157  # local BAs and the 7-Scenes loop's global BA stay dense


@pytest.mark.parametrize("sensor", ["stereo", "rgbd"])
def test_global_ba_sparse_reaches_the_dense_poses(sensor, monkeypatch):
    problem, truth = make_ba_problem(n_keyframes=60, n_points=1200, sensor=sensor, seed=2)
    dense = global_bundle_adjustment(problem, GlobalBAConfig())  # 59 variable keyframes <= 200: dense
    calls = []
    solve = schur_sparse.SparseCameraSystem.solve
    monkeypatch.setattr(schur_sparse.SparseCameraSystem, "solve", lambda self, *a: calls.append(1) or solve(self, *a))
    sparse = global_bundle_adjustment(problem, dataclasses.replace(GlobalBAConfig(), sparse_min_cameras=50))
    assert len(calls) >= sparse.iterations > 0  # the sparse path ran every LM step
    assert sparse.iterations == dense.iterations
    # measured (x86-64, and with OPENBLAS_CORETYPE=SandyBridge NUMBA_CPU_NAME=generic): positions 6e-13 m,
    # rotations 7e-14, points 2e-12 m apart after 8-11 LM iterations (the BA's own error vs truth: 3-4 cm);
    # the bounds leave a 1000x margin for other CPUs' rounding
    assert np.abs(sparse.T_world_cam[:, :3, 3] - dense.T_world_cam[:, :3, 3]).max() < 1e-9
    assert np.abs(sparse.T_world_cam[:, :3, :3] - dense.T_world_cam[:, :3, :3]).max() < 1e-10
    assert np.abs(sparse.X_world - dense.X_world).max() < 1e-8
    assert np.array_equal(sparse.inlier_mask, dense.inlier_mask)
