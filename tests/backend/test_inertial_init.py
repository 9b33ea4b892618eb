"""Visual-inertial initialization (inertial-only MAP, Campos et al. ICRA 2020) on the synthetic IMU
with exact ground truth, and on REAL EuRoC MH_01 (hand-held, 4 s) from vslam's own stereo and
monocular runs against EuRoC's ground truth (``state_groundtruth_estimate0``: body pose, b_w, b_a).

Measured run time of :func:`initialize_inertial` (``solve_time_s``, median of 7, on a 2-core machine
at load 7): 41-55 ms for 14-21 keyframes, 87 ms for 33, 106-122 ms for 41 (2.6-3 ms per keyframe:
the preintegration and GTSAM's bias-Jacobian read-out; LM takes 2-3 iterations on MH_01).
"""
from __future__ import annotations

import numpy as np
import pytest

from vslam.backend.inertial_init import (
    InertialInitConfig, gravity_aligned_poses, gravity_aligned_trajectory, initialize_inertial,
)
from vslam.backend.inertial_residual import imu_interval, make_pair, residual
from vslam.datasets.imu import load_imu_csv, read_imu_calibration
from vslam.datasets.synthetic import SyntheticConfig
from vslam.datasets.synthetic.imu import SyntheticImuConfig, imu_motion, write_imu
from vslam.geometry.lie import so3_exp
from vslam.inertial import ImuBias, make_params, rotation_to_up

SYN = SyntheticConfig(n_frames=300)                  # the default loop, 30 fps, up to 0.86 rad/s
SYN_TIMES = np.round(np.arange(0, 61, 3) / SYN.fps, 6)  # 21 keyframes every 0.1 s over 2 s
R_VIS_WORLD = so3_exp(np.array([0.3, -0.5, 1.0]))    # the visual world is not gravity-aligned
S_TRUE = 0.4                                         # metres per monocular visual unit
#: Loose bias priors (1 rad/s, 1 m/s^2): the synthetic biases (0.08 rad/s, 0.14 m/s^2) are recovered
#: from the data, not pulled to zero.
LOOSE = InertialInitConfig(gyro_bias_sigma=1.0, accel_bias_sigma=1.0)
SEEDS = (0, 1, 2, 3)


def synthetic(tmp_path, seed: int, noise: bool = True):
    """The synthetic IMU written by the renderer's writer and read back as a run would: samples,
    calibration, and the true biases averaged over the keyframe window."""
    cfg = SyntheticImuConfig(noise=noise, seed=seed)
    sim = write_imu(tmp_path / f"imu{seed}{noise}", SYN, cfg)
    folder = tmp_path / f"imu{seed}{noise}"
    imu = load_imu_csv(folder / "data.csv")
    calib = read_imu_calibration([folder / "camchain-imucam.yaml", folder / "sensor.yaml"])
    t = sim.timestamps_ns * 1e-9
    m = (t >= SYN_TIMES[0]) & (t <= SYN_TIMES[-1])
    return imu, calib, sim.gyro_bias[m].mean(axis=0), sim.accel_bias[m].mean(axis=0), cfg


def visual_poses(mono: bool) -> np.ndarray:
    """Exact camera poses at the keyframes in a rotated visual world (and divided by ``S_TRUE`` for mono)."""
    T, *_ = imu_motion(SYN, SYN_TIMES, np.eye(4))
    T[:, :3, :3] = R_VIS_WORLD @ T[:, :3, :3]
    T[:, :3, 3] = T[:, :3, 3] @ R_VIS_WORLD.T / (S_TRUE if mono else 1.0)
    return T


def gravity_error_deg(R_world_gravityaligned: np.ndarray, up_world: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip(R_world_gravityaligned[:, 2] @ up_world, -1.0, 1.0))))


def test_residual_jacobians_match_numerical_differences(tmp_path):
    """The analytic Jacobians of the inertial residual against central differences (step 1e-6 along
    the GTSAM retraction of each key: ``Unit3.retract``, vectors additive). Measured max difference
    ~1e-8 (differences of O(1) entries at step 1e-6); a sign or a missing ``dt`` is off by O(1)."""
    import gtsam

    imu, calib, *_ = synthetic(tmp_path, 0)
    T = visual_poses(mono=True)
    itv = imu_interval(imu, SYN_TIMES[4], SYN_TIMES[6], make_params(calib, np.zeros(3)), ImuBias())
    pair = make_pair(T[4], T[6], calib)
    rng = np.random.default_rng(1)
    u = gtsam.Unit3(np.array([0.1, -0.2, 1.0]))
    x = {"s": 0.3, "vi": rng.normal(size=3), "vj": rng.normal(size=3), "b": rng.normal(scale=0.05, size=6)}

    def r_of(u_, x_):
        return residual(pair, itv, np.asarray(u_.point3()), np.asarray(u_.basis()), x_["s"], x_["vi"], x_["vj"],
                        x_["b"], 9.81)[0]

    _r, J = residual(pair, itv, np.asarray(u.point3()), np.asarray(u.basis()), x["s"], x["vi"], x["vj"], x["b"],
                     9.81, jacobians=True)
    h = 1e-6
    num_u = np.stack([(r_of(u.retract(h * e), x) - r_of(u.retract(-h * e), x)) / (2 * h) for e in np.eye(2)], 1)
    np.testing.assert_allclose(J[0], num_u, atol=1e-6)
    for name, dim, blocks in (("s", 1, [J[1]]), ("vi", 3, [J[2]]), ("vj", 3, [J[3]]), ("b", 6, [J[4], J[5]])):
        cols = []
        for k in range(dim):
            plus, minus = dict(x), dict(x)
            if name == "s":
                plus[name], minus[name] = x[name] + h, x[name] - h
            else:
                plus[name] = x[name] + h * np.eye(dim)[k]
                minus[name] = x[name] - h * np.eye(dim)[k]
            cols.append((r_of(u, plus) - r_of(u, minus)) / (2 * h))
        np.testing.assert_allclose(np.hstack(blocks), np.stack(cols, 1), atol=1e-6, err_msg=name)


@pytest.mark.parametrize("mono", [False, True], ids=["stereo", "mono"])
def test_synthetic_recovers_scale_gravity_biases(tmp_path, mono):
    """Exact poses, EuRoC-like IMU noise (4 seeds), 21 keyframes over 2 s of the synthetic loop.

    Tolerances are derived from the noise: 4 posterior standard deviations (GTSAM's marginals at
    the optimum: the IMU noise densities carried through the preintegration covariance, whose
    chi-square the preintegration tests check), the bias ones widened by the bias random walk's
    spread over the window (``sigma_rw sqrt(T)``: the estimate is one bias for a wandering one).
    The posterior stds themselves are pinned so the test is not vacuous: stereo gravity 0.029 deg,
    b_g 1.2e-4 rad/s, b_a 4.9e-3 m/s^2; mono scale 3.7 % (relative), gravity 0.055 deg, b_a 0.021.
    Measured worst over the seeds: stereo gravity 2.8 sigma, b_a 3.3 sigma (without the walk's
    widening); mono scale 1.4 sigma (relative error up to 5 %), gravity 2.1 sigma.
    Noise-free the errors are under 0.1 sigma (the loose prior's pull only)."""
    T = visual_poses(mono)
    up = R_VIS_WORLD[:, 2]
    for seed in SEEDS:
        imu, calib, b_g, b_a, cfg = synthetic(tmp_path, seed)
        r = initialize_inertial(SYN_TIMES, T, imu, calib, monocular=mono, config=LOOSE)
        assert r.success, r.reason
        window = SYN_TIMES[-1] - SYN_TIMES[0]
        tol_g = 4 * np.hypot(r.std_gyro_bias, cfg.gyro_random_walk * np.sqrt(window))
        tol_a = 4 * np.hypot(r.std_accel_bias, cfg.accel_random_walk * np.sqrt(window))
        assert gravity_error_deg(r.R_world_gravityaligned, up) < 4 * r.std_gravity_deg, seed
        assert np.all(np.abs(r.bias.gyro - b_g) < tol_g), (seed, r.bias.gyro - b_g, tol_g)
        assert np.all(np.abs(r.bias.accel - b_a) < tol_a), (seed, r.bias.accel - b_a, tol_a)
        if mono:
            assert abs(r.scale - S_TRUE) < 4 * r.std_scale, (seed, r.scale, r.std_scale)
        else:
            assert r.scale == 1.0
    assert r.std_gravity_deg < (0.08 if mono else 0.04)
    assert r.std_gyro_bias.max() < 2e-4 and r.std_accel_bias.max() < (0.03 if mono else 0.007)
    if mono:
        assert r.std_scale / S_TRUE < 0.05
    # noise-free: only the (loose) prior moves the estimate
    imu, calib, b_g, b_a, _cfg = synthetic(tmp_path, 0, noise=False)
    r = initialize_inertial(SYN_TIMES, T, imu, calib, monocular=mono, config=LOOSE)
    assert gravity_error_deg(r.R_world_gravityaligned, up) < 0.1 * r.std_gravity_deg
    assert np.all(np.abs(r.bias.accel - b_a) < 0.25 * r.std_accel_bias)
    assert abs(r.scale - (S_TRUE if mono else 1.0)) <= 0.1 * max(r.std_scale, 1e-9)


def test_apply_to_poses_and_velocities(tmp_path):
    """The helper maps the visual world onto the gravity-aligned metric one: on exact synthetic
    poses (mono, noise-free) the aligned poses equal the true ones up to a yaw about z and a
    translation (z axis of every camera within 0.01 deg of the truth's; distances metric to 0.1 %),
    and the velocities, returned in the aligned frame, have the true speeds (to 1 mm/s)."""
    imu, calib, *_ = synthetic(tmp_path, 0, noise=False)
    T_vis = visual_poses(mono=True)
    r = initialize_inertial(SYN_TIMES, T_vis, imu, calib, monocular=True, config=LOOSE)
    T_true, *_ = imu_motion(SYN, SYN_TIMES, np.eye(4))
    T_al = gravity_aligned_poses(T_vis, r)
    # the world z axis seen from each camera: the same in both (yaw-free comparison)
    z_al, z_true = T_al[:, 2, :3], T_true[:, 2, :3]
    assert np.degrees(np.arccos(np.clip(np.sum(z_al * z_true, 1), -1, 1))).max() < 0.01
    d_al = np.linalg.norm(np.diff(T_al[:, :3, 3], axis=0), axis=1)
    d_true = np.linalg.norm(np.diff(T_true[:, :3, 3], axis=0), axis=1)
    np.testing.assert_allclose(d_al, d_true, rtol=1e-3)
    _T, v_true, *_ = imu_motion(SYN, calib.imu_time(SYN_TIMES), calib.T_cam_imu)
    np.testing.assert_allclose(np.linalg.norm(r.velocities, axis=1), np.linalg.norm(v_true, axis=1), atol=1e-3)
    np.testing.assert_allclose(r.velocities[:, 2], v_true[:, 2], atol=1e-3)  # z is z in both
    from vslam.trajectory import Trajectory

    traj = gravity_aligned_trajectory(Trajectory(SYN_TIMES, T_vis), r)
    np.testing.assert_allclose(traj.T_world_cam, T_al)
    for up in ([0.3, -0.2, 0.9], [0.0, 0.0, -1.0], [0.0, 0.0, 1.0]):   # R_wg = rotation_to_up(up)^T: z -> up
        up = np.asarray(up) / np.linalg.norm(up)
        np.testing.assert_allclose(rotation_to_up(up) @ up, [0.0, 0.0, 1.0], atol=1e-12)


def test_refusals(tmp_path):
    """Too few keyframes, too short a window and an IMU that does not cover the keyframes are
    refused with the reason (no acceleration change: :func:`test_refuses_at_rest`)."""
    imu, calib, *_ = synthetic(tmp_path, 0)
    T = visual_poses(mono=True)
    r = initialize_inertial(SYN_TIMES[:6], T[:6], imu, calib, monocular=True)
    assert not r.success and "too few keyframes" in r.reason
    t_short = np.round(np.arange(12) / SYN.fps, 6)   # 12 keyframes over 0.37 s
    T_short, *_ = imu_motion(SYN, t_short, np.eye(4))
    r = initialize_inertial(t_short, T_short, imu, calib)
    assert not r.success and "too short" in r.reason
    r = initialize_inertial(SYN_TIMES + 20.0, T, imu, calib)
    assert not r.success and "do not cover" in r.reason
    with pytest.raises(ValueError, match="did not succeed"):
        gravity_aligned_poses(T, r)


@pytest.mark.shared
def test_refuses_at_rest(shared_data):
    """EuRoC V1_01 (the MAV at rest, 2 s): the world-frame specific force varies by 0.043 m/s^2
    (measured) across the intervals, under the 0.1 threshold; the synthetic loop gives 0.24, MH_01's
    hand-held motion 1.7. Refused: use ``vslam.inertial.estimate_static`` there."""
    from vslam.datasets import open_dataset

    ds = open_dataset(shared_data / "euroc_V1_01_easy_40frames", sensor="stereo")
    gt = ds.ground_truth()
    sel = np.arange(0, len(gt), 3)
    r = initialize_inertial(gt.timestamps[sel], gt.T_world_cam[sel], ds.imu, ds.imu_calibration.with_camera(ds.T_cam0_rect))
    assert not r.success and "excitation" in r.reason


# --- REAL EuRoC MH_01 (80 frames, 4 s hand-held): keyframes of vslam's own runs ------------------

MH01 = "euroc_mh01_vi_80"
WINDOW_S = 2.0   # the keyframes of the first 2 s of motion (the mono goal; ORB-SLAM3 waits 1 s stereo)


@pytest.fixture(scope="module")
def mh01_runs(shared_data, tmp_path_factory):
    """vslam stereo and mono runs of the clip, once for the module: ``{sensor: (dataset, run dir)}``."""
    from vslam.api import run_path
    from vslam.datasets import open_dataset

    out = {}
    for sensor in ("stereo", "mono"):
        run = tmp_path_factory.mktemp(f"mh01_{sensor}")
        run_path(shared_data / MH01, run, sensor=sensor, prefetch="none")
        out[sensor] = (open_dataset(shared_data / MH01, sensor=sensor), run)
    return out


def initialize_from_run(ds, run, mono: bool):
    """The initialization on the run's keyframes of the first :data:`WINDOW_S` seconds; with the
    ground-truth gravity direction in the first keyframe's camera frame and the estimated one."""
    from vslam.trajectory import read_trajectory

    kf = read_trajectory(run / "keyframes.txt")
    m = kf.timestamps <= kf.timestamps[0] + WINDOW_S + 1e-6
    t, T = kf.timestamps[m], kf.T_world_cam[m]
    r = initialize_inertial(t, T, ds.imu, ds.imu_calibration.with_camera(ds.T_cam0_rect), monocular=mono)
    assert r.success, r.reason
    gt = ds.ground_truth()                           # T_world_cam, EuRoC's world: z up
    R_w_cam0 = gt.T_world_cam[np.argmin(np.abs(gt.timestamps - t[0])), :3, :3]
    g_gt = R_w_cam0.T @ np.array([0.0, 0.0, -1.0])   # yaw-free: gravity seen from the first keyframe
    g_est = T[0, :3, :3].T @ r.gravity_world / np.linalg.norm(r.gravity_world)
    angle = float(np.degrees(np.arccos(np.clip(g_gt @ g_est, -1.0, 1.0))))
    return r, t, angle


def gt_biases(shared_data, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """EuRoC's estimated b_w, b_a (``state_groundtruth_estimate0``) averaged over the window."""
    gt = np.loadtxt(shared_data / MH01 / "mav0" / "state_groundtruth_estimate0" / "data.csv", delimiter=",",
                    comments="#")
    m = (gt[:, 0] * 1e-9 >= t[0]) & (gt[:, 0] * 1e-9 <= t[-1])
    return gt[m, 11:14].mean(axis=0), gt[m, 14:17].mean(axis=0)


@pytest.mark.shared
def test_stereo_gravity_and_biases_on_euroc(mh01_runs, shared_data):
    """Stereo keyframes of the first 2 s (17 keyframes), default priors (ORB-SLAM3's). Measured:
    gravity 0.80 deg from the ground truth's (tolerance 1.2; the issue's goal for the map is 2),
    gyro bias within 0.0009 rad/s of EuRoC's on every axis (tolerance 0.003; the bias is 0.08 rad/s,
    ignoring it misses by that), accelerometer bias 0.129 m/s^2 from EuRoC's (norm; tolerance 0.2).

    The gravity and accelerometer-bias errors are one: a horizontal ``b_a`` error ``d`` tilts
    gravity by ``d / g`` (0.129 / 9.81 = 0.75 deg), and 2 s of motion separate them poorly
    (``b_a`` is also EuRoC's estimate, not a measurement). With the ground-truth poses instead of
    vslam's the same window gives 0.61 deg."""
    ds, run = mh01_runs["stereo"]
    r, t, angle = initialize_from_run(ds, run, mono=False)
    b_w, b_a = gt_biases(shared_data, t)
    assert len(t) >= 10 and r.scale == 1.0
    assert angle < 1.2, angle
    assert np.abs(r.bias.gyro - b_w).max() < 0.003, (r.bias.gyro, b_w)
    assert np.linalg.norm(r.bias.accel - b_a) < 0.2, (r.bias.accel, b_a)
    assert r.solve_time_s < 5.0   # measured 0.06-0.1 s; only a gross slow-down fails this


@pytest.mark.shared
def test_mono_scale_on_euroc(mh01_runs, shared_data):
    """Monocular keyframes of the first 2 s (14 keyframes; the issue: initialized within 2 s of
    motion), default priors (ORB-SLAM3's: ``b_a`` held at zero). Measured: scale 0.5873 where the
    Sim(3) alignment of the whole run to the ground truth finds 0.5861 (+0.2 %; tolerance 3 %, the
    issue's goal 5 %; a 1.5 s window gives +1.7 %); the whole trajectory, scaled and rotated by the
    result, has an SE(3)-aligned ATE of 0.0026 m (the run's Sim(3) ATE: 0.0026; tolerance 0.006,
    the issue's goal 0.02); gravity 0.90 deg from the ground truth's (tolerance 1.3: EuRoC's
    ``b_a``, 0.16 m/s^2, held at zero tilts it by 0.16 / 9.81 = 0.9 deg)."""
    from vslam.eval.evaluate import evaluate_trajectories
    from vslam.trajectory import read_trajectory

    ds, run = mh01_runs["mono"]
    r, t, angle = initialize_from_run(ds, run, mono=True)
    gt = ds.ground_truth()
    full = read_trajectory(run / "trajectory.txt")
    sim3_scale = evaluate_trajectories(full, gt, align="sim3").alignment.s
    assert abs(r.scale / sim3_scale - 1) < 0.03, (r.scale, sim3_scale)
    ate = evaluate_trajectories(gravity_aligned_trajectory(full, r), gt, align="se3").ate.rmse
    assert ate < 0.006, ate
    assert angle < 1.3, angle
    b_w, _b_a = gt_biases(shared_data, t)
    assert np.abs(r.bias.gyro - b_w).max() < 0.005, (r.bias.gyro, b_w)   # measured 0.0017
