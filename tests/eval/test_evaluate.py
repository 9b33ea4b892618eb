"""evaluate_trajectories / evaluate_files on the real trajectories, cross-checked against evo.

evo (GPL) is only the oracle here: ``evo.core.sync.associate_trajectories``, ``PosePath3D.align``,
``metrics.APE`` and ``metrics.RPE`` (delta 1 frame) through the Python API.
"""
from __future__ import annotations

import copy
import json

import numpy as np
import pytest

from vslam.errors import TrajectoryError
from vslam.eval import EvalConfig, evaluate_files, evaluate_trajectories
from vslam.trajectory import Trajectory

TUM_CASES = [
    ("tum/freiburg1_xyz-rgbdslam.txt", "tum/freiburg1_xyz-groundtruth.txt", 785),
    ("tum/freiburg1_xyz-ORB_kf_mono.txt", "tum/freiburg1_xyz-groundtruth.txt", 32),
    ("tum/fr2_desk_ORB.txt", "tum/fr2_desk_groundtruth.txt", 2174),
]


def evo_numbers(evo, ref, est, correct_scale: bool, cache: dict) -> dict:
    """evo's APE and RPE after ``align``. The rotation RPE does not depend on a Sim(3) alignment
    (a left-multiplied similarity cancels in relative poses), and evo's is slow (3 s on KITTI 00),
    so it is computed once per pair of trajectories via ``cache``."""
    est = copy.deepcopy(est)
    _, _, s = est.align(ref, correct_scale=correct_scale)
    m = evo.metrics
    out = {"scale": s}
    metrics = [("ape", m.APE(m.PoseRelation.translation_part)),
               ("rpe_t", m.RPE(m.PoseRelation.translation_part, 1, m.Unit.frames))]
    if "rpe_r" not in cache:
        metrics.append(("rpe_r", m.RPE(m.PoseRelation.rotation_angle_deg, 1, m.Unit.frames)))
    for key, metric in metrics:
        metric.process_data((ref, est))
        out[key] = metric.error
        out[key + "_stats"] = metric.get_all_statistics()
    cache.setdefault("rpe_r", out.get("rpe_r"))
    cache.setdefault("rpe_r_stats", out.get("rpe_r_stats"))
    return {**cache, **out}


def check_against_evo(ours, theirs) -> None:
    tol = 1e-5
    np.testing.assert_allclose(ours.ate_errors, theirs["ape"], rtol=0, atol=tol)
    np.testing.assert_allclose(ours.rpe_trans_errors, theirs["rpe_t"], rtol=0, atol=tol)
    n_rot = len(theirs["rpe_r"])  # the first n_rot pairs when evo ran on a prefix (KITTI 00)
    np.testing.assert_allclose(ours.rpe_rot_errors_deg[:n_rot], theirs["rpe_r"], rtol=0, atol=tol)
    for key in ("rmse", "mean", "median", "std", "max", "min"):
        assert getattr(ours.ate, key) == pytest.approx(theirs["ape_stats"][key], abs=tol)
        assert getattr(ours.rpe_trans, key) == pytest.approx(theirs["rpe_t_stats"][key], abs=tol)
        if n_rot == len(ours.rpe_rot_errors_deg):
            assert getattr(ours.rpe_rot_deg, key) == pytest.approx(theirs["rpe_r_stats"][key], abs=tol)
    assert ours.scale == pytest.approx(theirs["scale"], rel=1e-9)


@pytest.mark.parametrize("est_name,gt_name,n_matched", TUM_CASES)
def test_tum_matches_evo(shared_data, evo, est_name, gt_name, n_matched):
    d = shared_data / "trajectories"
    ref = evo.file_interface.read_tum_trajectory_file(str(d / gt_name))
    est = evo.file_interface.read_tum_trajectory_file(str(d / est_name))
    ref_sync, est_sync = evo.sync.associate_trajectories(ref, est, max_diff=0.01)
    assert est_sync.num_poses == n_matched
    cache: dict = {}
    for align, scale in (("se3", False), ("sim3", True)):
        # The official fr2/desk ground truth repeats one timestamp: keep_last, as the TUM tools.
        ours = evaluate_files(d / est_name, d / gt_name, align=align, duplicates="keep_last")
        assert ours.matched_poses == n_matched
        np.testing.assert_allclose(ours.est_aligned.timestamps, est_sync.timestamps, atol=1e-9)
        check_against_evo(ours, evo_numbers(evo, ref_sync, est_sync, scale, cache))


def test_orb_mono_needs_sim3(shared_data):
    d = shared_data / "trajectories/tum"
    se3 = evaluate_files(d / "freiburg1_xyz-ORB_kf_mono.txt", d / "freiburg1_xyz-groundtruth.txt")
    sim3 = evaluate_files(d / "freiburg1_xyz-ORB_kf_mono.txt", d / "freiburg1_xyz-groundtruth.txt", align="sim3")
    assert sim3.ate.rmse < 0.5 * se3.ate.rmse
    assert sim3.ate.rmse == pytest.approx(0.009755, abs=1e-5) and sim3.scale == pytest.approx(1.10562, abs=1e-4)


def test_kitti00_matches_evo_by_index(shared_data, evo):
    d = shared_data / "trajectories/kitti"
    ref = evo.file_interface.read_kitti_poses_file(str(d / "KITTI_00_gt.txt"))
    est = evo.file_interface.read_kitti_poses_file(str(d / "KITTI_00_ORB.txt"))
    # evo's rotation RPE takes ~1 ms per pose (scipy per matrix): check it on the first 1500 poses
    # (the rotation RPE does not depend on the alignment, so the unaligned prefix is the oracle).
    ref_p, est_p = copy.deepcopy(ref), copy.deepcopy(est)
    ref_p.reduce_to_ids(np.arange(1500))
    est_p.reduce_to_ids(np.arange(1500))
    rot = evo.metrics.RPE(evo.metrics.PoseRelation.rotation_angle_deg, 1, evo.metrics.Unit.frames)
    rot.process_data((ref_p, est_p))
    assert len(rot.error) == 1499
    cache: dict = {"rpe_r": rot.error, "rpe_r_stats": None}
    for align, scale in (("se3", False), ("sim3", True)):
        ours = evaluate_files(d / "KITTI_00_ORB.txt", d / "KITTI_00_gt.txt", align=align, kitti=True)
        assert ours.config.by_index and ours.matched_poses == 4541
        check_against_evo(ours, evo_numbers(evo, ref, est, scale, cache))
        # SE(3) leaves the KITTI metric as the devkit's; Sim(3) also removes ORB-SLAM2's scale drift.
        assert ours.kitti.t_err_percent == pytest.approx(0.6997 if align == "se3" else 0.6277, abs=5e-4)
    # With the GT times file and an untimed estimate: still by index (the estimate has no times).
    timed = evaluate_files(d / "KITTI_00_ORB.txt", d / "KITTI_00_gt.txt", gt_times=d / "KITTI_00_gt_times.txt")
    assert timed.config.by_index and timed.ate.rmse == pytest.approx(1.30345, abs=1e-5)
    both = evaluate_files(d / "KITTI_00_ORB.txt", d / "KITTI_00_gt.txt", est_times=d / "KITTI_00_gt_times.txt",
                          gt_times=d / "KITTI_00_gt_times.txt")
    assert not both.config.by_index and both.matched_poses == 4541


def test_to_dict_keys_and_json(shared_data):
    d = shared_data / "trajectories/tum"
    res = evaluate_files(d / "freiburg1_xyz-rgbdslam.txt", d / "freiburg1_xyz-groundtruth.txt", align="sim3")
    out = json.loads(json.dumps(res.to_dict()))
    for key in ("ate_rmse", "ate_mean", "ate_median", "ate_max", "ate_std", "rpe_trans_rmse",
                "rpe_rot_deg_rmse", "rpe_trans_mean", "matched_poses", "scale", "alignment"):
        assert key in out
    assert out["matched_poses"] == 785 and out["alignment"] == "sim3"
    assert out["ate_rmse"] == pytest.approx(res.ate.rmse)
    assert "kitti_t_err_percent" not in out
    assert "ATE (m)" in res.summary()


def synthetic(n: int = 60) -> tuple[Trajectory, Trajectory]:
    t = np.linspace(0, 6, n)
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, 3] = np.stack([np.cos(t), np.sin(t), 0.1 * t], 1)
    gt = Trajectory(t, T)
    est_T = T.copy()
    est_T[:, :3, 3] = 0.5 * T[:, :3, 3] + [3.0, 0, 0]
    return Trajectory(t + 0.003, est_T), gt


def test_config_overrides_and_sim3_exact():
    est, gt = synthetic()
    res = evaluate_trajectories(est, gt, EvalConfig(align="sim3"), rpe_delta=0.5, rpe_delta_unit="m")
    assert res.scale == pytest.approx(2.0, rel=1e-12)
    assert res.ate.max < 1e-12 and res.rpe_trans.max < 1e-12
    assert res.config.rpe_delta_unit == "m" and len(res.rpe_pairs) > 5
    se3 = evaluate_trajectories(est, gt)
    assert se3.ate.rmse > 0.1


def test_evaluation_errors():
    est, gt = synthetic()
    with pytest.raises(TrajectoryError, match="no common timestamps"):
        evaluate_trajectories(est, gt, offset=100.0)
    with pytest.raises(TrajectoryError, match="use a smaller --delta"):
        evaluate_trajectories(est, gt, rpe_delta=100, rpe_delta_unit="m")
    with pytest.raises(TrajectoryError, match="shorter than every segment length"):
        evaluate_trajectories(est, gt, kitti=True)
    with pytest.raises(TrajectoryError, match="need at least 2"):
        evaluate_trajectories(est.subset(np.array([0])), gt)
