"""Local and global BA on seeded synthetic problems with exact truth (see vslam/backend/synthetic.py)."""
from __future__ import annotations

import dataclasses
import importlib.util
from pathlib import Path

import numpy as np
import pytest

from vslam.backend.bundle_adjustment import global_bundle_adjustment, local_bundle_adjustment
from vslam.backend.config import GlobalBAConfig, LocalBAConfig
from vslam.backend.problem import BAProblem
from vslam.backend.synthetic import make_ba_problem
from vslam.errors import ConfigError, GeometryError

_spec = importlib.util.spec_from_file_location("_backend_helpers", Path(__file__).with_name("_helpers.py"))
_helpers = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_helpers)
pose_errors, rms = _helpers.pose_errors, _helpers.rms


def _free(problem: BAProblem) -> np.ndarray:
    return ~np.isin(problem.kf_ids, problem.fixed_kf_ids)


def test_local_ba_stereo_accuracy_outliers_and_gauge():
    # 10 KFs, 3000 points 4-12 m, ~13k observations, 1 px noise, 5 % outliers, 2 cm / 0.5 deg perturbation
    problem, truth = make_ba_problem(sensor="stereo", seed=1)
    free = _free(problem)
    t0, r0 = pose_errors(problem.T_world_cam[free], truth.T_world_cam[free])
    assert rms(t0) > 0.025 and rms(r0) > 0.5  # the perturbation is real
    res = local_bundle_adjustment(problem)
    t1, r1 = pose_errors(res.T_world_cam[free], truth.T_world_cam[free])
    assert rms(t1) < 0.005, rms(t1)  # measured 2.3 mm (of 40 mm initially)
    assert rms(r1) < 0.05, rms(r1)  # measured 0.018 deg
    # the gross outliers (15-60 px) are flagged; few inliers are lost (chi2 95 %: ~5 % expected)
    recall = np.mean(~res.inlier_mask[truth.outlier])
    false_alarm = np.mean(~res.inlier_mask[~truth.outlier])
    assert recall >= 0.9, recall
    assert false_alarm < 0.08, false_alarm
    assert res.final_rms_px < 1.0 < res.initial_rms_px
    assert res.final_cost < 0.1 * res.initial_cost
    # fixed keyframes do not move, ids come back in order
    np.testing.assert_array_equal(res.T_world_cam[~free], problem.T_world_cam[~free])
    np.testing.assert_array_equal(res.kf_ids, problem.kf_ids)
    np.testing.assert_array_equal(res.pt_ids, problem.pt_ids)
    assert set(res.summary()) >= {"initial_cost", "final_cost", "iterations", "time_s", "inliers"}


# no chi-square rejection: both runs keep every observation, so the minimum is the same
_KEEP_ALL = dict(chi2_mono=1e9, chi2_stereo=1e9, relative_tolerance=1e-10, iterations_refine=30)


def test_local_ba_reaches_the_same_minimum_as_from_truth():
    problem, truth = make_ba_problem(sensor="stereo", n_points=1200, outlier_fraction=0.0, seed=3)
    config = LocalBAConfig(**_KEEP_ALL)
    res = local_bundle_adjustment(problem, config)
    oracle = local_bundle_adjustment(dataclasses.replace(problem, T_world_cam=truth.T_world_cam, X_world=truth.X_world), config)
    dt, dr = pose_errors(res.T_world_cam, oracle.T_world_cam)
    assert dt.max() < 1e-6 and dr.max() < 1e-5, (dt.max(), dr.max())
    assert np.abs(res.X_world - oracle.X_world).max() < 1e-4


@pytest.mark.parametrize("sensor", ["mono", "stereo", "rgbd"])
def test_noise_free_problem_converges_to_the_truth(sensor):
    problem, truth = make_ba_problem(sensor=sensor, n_points=800, noise_px=0.0, outlier_fraction=0.0, seed=2)
    res = local_bundle_adjustment(problem)
    dt, dr = pose_errors(res.T_world_cam, truth.T_world_cam)
    assert dt.max() < 1e-6 and dr.max() < 1e-5
    # a monocular point seen by one keyframe has no depth information; every other point is exact
    n_obs = np.bincount(problem.pt_index(problem.obs_pt), minlength=problem.num_points)
    assert np.abs(res.X_world - truth.X_world)[n_obs >= 2].max() < 1e-4
    assert res.inlier_mask.all()


def test_mono_only_with_two_fixed_keyframes():
    problem, truth = make_ba_problem(sensor="mono", seed=0)
    assert len(problem.fixed_kf_ids) == 2 and np.all(np.isnan(problem.obs_u_right))
    free = _free(problem)
    res = local_bundle_adjustment(problem)
    t1, r1 = pose_errors(res.T_world_cam[free], truth.T_world_cam[free])
    assert rms(t1) < 0.006, rms(t1)  # measured 3.6 mm (of 43 mm initially); the two fixed KFs hold the scale
    assert rms(r1) < 0.05, rms(r1)
    assert np.mean(~res.inlier_mask[truth.outlier]) >= 0.9
    np.testing.assert_array_equal(res.T_world_cam[~free], problem.T_world_cam[~free])


def test_rgbd_depth_as_virtual_stereo():
    problem, truth = make_ba_problem(sensor="rgbd", seed=3)
    free = _free(problem)
    res = local_bundle_adjustment(problem)
    t1, r1 = pose_errors(res.T_world_cam[free], truth.T_world_cam[free])
    assert rms(t1) < 0.008 and rms(r1) < 0.06, (rms(t1), rms(r1))
    assert np.mean(~res.inlier_mask[truth.outlier]) >= 0.9


def test_global_ba_fixes_the_first_keyframe():
    problem, truth = make_ba_problem(n_keyframes=20, n_points=2000, sensor="stereo", n_fixed=1, seed=4)
    problem = dataclasses.replace(problem, fixed_kf_ids=np.zeros(0, np.int64))
    res = global_bundle_adjustment(problem)
    np.testing.assert_array_equal(res.T_world_cam[0], problem.T_world_cam[0])
    t1, r1 = pose_errors(res.T_world_cam[1:], truth.T_world_cam[1:])
    t0, _ = pose_errors(problem.T_world_cam[1:], truth.T_world_cam[1:])
    assert rms(t1) < 0.3 * rms(t0) and rms(t1) < 0.01, (rms(t0), rms(t1))  # measured 33 -> 7.3 mm
    assert rms(r1) < 0.06
    assert np.mean(~res.inlier_mask[truth.outlier]) >= 0.9


def test_gtsam_solver_reaches_the_same_estimate():
    problem, truth = make_ba_problem(sensor="stereo", n_points=400, seed=6)
    ours = local_bundle_adjustment(problem, LocalBAConfig(solver="schur"))
    ref = local_bundle_adjustment(problem, LocalBAConfig(solver="gtsam"))
    dt, dr = pose_errors(ours.T_world_cam, ref.T_world_cam)
    assert dt.max() < 1e-5 and dr.max() < 1e-4, (dt.max(), dr.max())  # measured 1e-6 m
    assert np.mean(ours.inlier_mask == ref.inlier_mask) > 0.99
    # monocular (weaker): with the same observations kept, both land on the same minimum
    mono, _ = make_ba_problem(sensor="mono", n_points=300, outlier_fraction=0.0, seed=6)
    a = local_bundle_adjustment(mono, LocalBAConfig(solver="schur", **_KEEP_ALL))
    b = local_bundle_adjustment(mono, LocalBAConfig(solver="gtsam", **_KEEP_ALL))
    dt, dr = pose_errors(a.T_world_cam, b.T_world_cam)
    assert dt.max() < 1e-5 and dr.max() < 1e-4, (dt.max(), dr.max())
    # RGB-D (virtual-baseline stereo factors) with per-octave sigmas 1.2 ** (0..3)
    rgbd, _ = make_ba_problem(sensor="rgbd", n_points=300, outlier_fraction=0.0, max_octave=3, seed=6)
    a = local_bundle_adjustment(rgbd, LocalBAConfig(solver="schur", **_KEEP_ALL))
    b = local_bundle_adjustment(rgbd, LocalBAConfig(solver="gtsam", **_KEEP_ALL))
    dt, dr = pose_errors(a.T_world_cam, b.T_world_cam)
    assert dt.max() < 1e-5 and dr.max() < 1e-4, (dt.max(), dr.max())
    assert abs(a.final_cost - b.final_cost) < 1e-6 * b.final_cost


@pytest.mark.parametrize("sensor,overrides", [("rgbd", {"rgbd_residual": "disparity", "disparity_sigma_scale": 1.0}),
                                               ("stereo", {"stereo_residual": "disparity"}),
                                               ("rgbd", {"rgbd_residual": "disparity", "disparity_sigma_scale": 0.5})])
def test_gtsam_agrees_on_both_depth_residuals(sensor, overrides):
    """The disparity residual (GTSAM: the stereo factor with the equivalent full covariance on
    ``(u_left, u_right, v)``, also with its own sigma ``disparity_sigma_scale * sigma``) and the u_right
    residual reach the same minimum in both solvers, and the models are different estimators (their
    minima differ)."""
    problem, _ = make_ba_problem(sensor=sensor, n_points=300, outlier_fraction=0.0, max_octave=3, seed=7)
    default = local_bundle_adjustment(problem, LocalBAConfig(rgbd_residual="u_right", **_KEEP_ALL))
    a = local_bundle_adjustment(problem, LocalBAConfig(solver="schur", **overrides, **_KEEP_ALL))
    b = local_bundle_adjustment(problem, LocalBAConfig(solver="gtsam", **overrides, **_KEEP_ALL))
    if "disparity_sigma_scale" in overrides:  # the scale is used, not ignored by both solvers
        same_sigma = {k: v for k, v in overrides.items() if k != "disparity_sigma_scale"}
        c = local_bundle_adjustment(problem, LocalBAConfig(solver="schur", **same_sigma, **_KEEP_ALL))
        assert pose_errors(a.T_world_cam, c.T_world_cam)[0].max() > 1e-5
    dt, dr = pose_errors(a.T_world_cam, b.T_world_cam)
    assert dt.max() < 1e-5 and dr.max() < 1e-4, (dt.max(), dr.max())
    assert abs(a.final_cost - b.final_cost) < 1e-6 * b.final_cost
    assert pose_errors(a.T_world_cam, default.T_world_cam)[0].max() > 1e-5


def test_points_seen_only_by_fixed_keyframes_stay_put_and_finite():
    problem, truth = make_ba_problem(sensor="stereo", n_points=500, seed=7)
    # make keyframe 0 the only observer of an extra point
    X_new = truth.X_world[:1] + np.array([[0.0, 0.0, 0.3]])
    T0 = truth.T_world_cam[0]
    Xc = (X_new - T0[:3, 3]) @ T0[:3, :3]
    uv = problem.camera.project(Xc)
    ur = uv[:, 0] - problem.camera.fx * problem.camera.baseline / Xc[:, 2]
    p = dataclasses.replace(
        problem,
        pt_ids=np.append(problem.pt_ids, 99999), X_world=np.vstack([problem.X_world, X_new]),
        obs_kf=np.append(problem.obs_kf, problem.kf_ids[0]), obs_pt=np.append(problem.obs_pt, 99999),
        obs_uv=np.vstack([problem.obs_uv, uv]), obs_sigma=np.append(problem.obs_sigma, 1.0),
        obs_u_right=np.append(problem.obs_u_right, ur), obs_depth=np.append(problem.obs_depth, np.nan),
    )
    res = local_bundle_adjustment(p)
    assert np.all(np.isfinite(res.X_world))
    assert np.linalg.norm(res.X_world[-1] - X_new[0]) < 1e-6
    assert res.inlier_mask[-1]


def test_problem_validation_errors():
    problem, _ = make_ba_problem(sensor="stereo", n_points=50, seed=8)
    with pytest.raises(GeometryError, match="unknown point"):
        dataclasses.replace(problem, obs_pt=problem.obs_pt + 10**6)
    with pytest.raises(GeometryError, match="unknown keyframe"):
        dataclasses.replace(problem, fixed_kf_ids=np.array([-5]))
    with pytest.raises(GeometryError, match="finite"):
        X = problem.X_world.copy()
        X[0, 0] = np.nan
        dataclasses.replace(problem, X_world=X)
    with pytest.raises(GeometryError, match="observed twice"):
        dataclasses.replace(
            problem, obs_kf=np.append(problem.obs_kf, problem.obs_kf[0]), obs_pt=np.append(problem.obs_pt, problem.obs_pt[0]),
            obs_uv=np.vstack([problem.obs_uv, problem.obs_uv[:1]]), obs_sigma=np.append(problem.obs_sigma, 1.0),
            obs_u_right=np.append(problem.obs_u_right, np.nan), obs_depth=np.append(problem.obs_depth, np.nan),
        )
    with pytest.raises(ConfigError):
        LocalBAConfig(solver="ceres")
    with pytest.raises(ConfigError):
        GlobalBAConfig(iterations_robust=0, iterations_refine=0)


def test_problem_index_lookup_with_unsorted_ids_and_cached_observation_rows():
    problem, _ = make_ba_problem(sensor="stereo", n_points=50, seed=8)
    # reversed ids: the sorted fast path does not apply; rows must still follow the given order
    rev_pt = problem.pt_ids[::-1].copy()
    p = dataclasses.replace(problem, pt_ids=rev_pt, X_world=problem.X_world[::-1].copy())
    rows = p.pt_index(p.obs_pt)
    np.testing.assert_array_equal(p.pt_ids[rows], p.obs_pt)
    np.testing.assert_array_equal(p.pt_index(p.obs_pt.copy()), rows)  # a fresh array, not the cached rows
    np.testing.assert_array_equal(p.kf_ids[p.kf_index(p.obs_kf)], p.obs_kf)
    np.testing.assert_array_equal(p.pt_index(rev_pt[[3, 0]]), [3, 0])
    with pytest.raises(GeometryError, match="unknown point"):
        p.pt_index(np.array([10**6]))


def test_problem_observation_row_hint_is_checked_not_trusted():
    problem, _ = make_ba_problem(sensor="stereo", n_points=50, seed=8)
    kf_rows, pt_rows = problem.kf_index(problem.obs_kf.copy()), problem.pt_index(problem.obs_pt.copy())
    good = dataclasses.replace(problem, obs_rows=(kf_rows, pt_rows))
    assert good.obs_rows is None  # consumed
    np.testing.assert_array_equal(good.pt_index(good.obs_pt), pt_rows)
    np.testing.assert_array_equal(good.kf_index(good.obs_kf), kf_rows)
    wrong = dataclasses.replace(problem, obs_rows=((kf_rows + 1) % problem.num_keyframes, pt_rows[::-1].copy()))
    np.testing.assert_array_equal(wrong.pt_index(wrong.obs_pt), pt_rows)  # searched instead
    np.testing.assert_array_equal(wrong.kf_index(wrong.obs_kf), kf_rows)
    with pytest.raises(GeometryError, match="unknown point"):  # a hint does not bypass the id check
        dataclasses.replace(problem, obs_pt=problem.obs_pt + 10**6, obs_rows=(kf_rows, pt_rows))
    with pytest.raises(GeometryError, match="unique"):
        dataclasses.replace(problem, pt_ids=np.sort(np.r_[problem.pt_ids[:-1], problem.pt_ids[0]]))
