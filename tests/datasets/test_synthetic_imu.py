"""The synthetic IMU: opt-in files in EuRoC layout, exact ground truth, EuRoC-like seeded noise."""
from __future__ import annotations

import numpy as np
import pytest

from vslam.datasets.imu import load_imu_csv, read_imu_calibration
from vslam.datasets.synthetic import SyntheticConfig, render_sequence
from vslam.datasets.synthetic.imu import SyntheticImuConfig, simulate_imu
from vslam.datasets.synthetic.trajectory import make_path, path_at
from vslam.trajectory import read_tum

# 20 fps so every frame time is on the 200 Hz grid; 60 frames, a 3 s lap; tiny images (fast)
SMALL = SyntheticConfig(n_frames=60, fps=20.0, width=32, height=24, fx=25.0, fy=25.0, cx=15.5, cy=11.5,
                        start_time=100.0, laps=0.3)


def test_path_at_matches_frames():
    """The continuous path the IMU differentiates passes through the rendered frame poses."""
    for kind in ("loop", "forward"):
        np.testing.assert_allclose(path_at(kind, np.arange(300), 300), make_path(kind, 300), atol=1e-15)


def test_default_output_has_no_imu(tmp_path):
    render_sequence(tmp_path / "seq", SyntheticConfig(n_frames=2, width=32, height=24, fx=25, fy=25, cx=15.5, cy=11.5))
    assert not (tmp_path / "seq" / "imu0").exists()


def test_written_imu_reads_back(tmp_path):
    """``imu0/`` in EuRoC layout: the samples (17 significant digits), the calibration from its
    sensor.yaml + Kalibr camchain, and ground truth agreeing with the camera's groundtruth.txt."""
    imu_cfg = SyntheticImuConfig(seed=3)
    out = render_sequence(tmp_path / "seq", SMALL, imu=imu_cfg)
    sim = simulate_imu(SMALL, imu_cfg)
    imu = load_imu_csv(out / "imu0" / "data.csv")
    assert len(imu) == len(sim.timestamps) == 1 + int(round((imu_cfg.lead_s + 59 / 20.0) * 200))
    np.testing.assert_array_equal(imu.timestamps, sim.timestamps)  # integer ns both ways
    np.testing.assert_array_equal(imu.gyro, sim.gyro)  # %.17g round-trips a float64
    np.testing.assert_array_equal(imu.accel, sim.accel)
    calib = read_imu_calibration([out / "imu0" / "sensor.yaml", out / "imu0" / "camchain-imucam.yaml"])
    np.testing.assert_allclose(calib.T_imu_cam, imu_cfg.calibration().T_imu_cam, atol=1e-15)
    assert calib.defaulted == () and calib.rate_hz == 200
    # sensor.yaml alone, with the body being the camera (T_body_cam = I), says the same
    alone = read_imu_calibration(out / "imu0" / "sensor.yaml", T_body_cam=np.eye(4))
    np.testing.assert_allclose(alone.T_imu_cam, calib.T_imu_cam, atol=1e-15)
    # ground truth: at the frame times, T_world_imu = T_world_cam T_cam_imu (groundtruth.txt has 9
    # decimals: 1e-9 m, and quaternions to 1e-9, i.e. rotations to ~2e-9)
    gt = np.loadtxt(out / "imu0" / "groundtruth.csv", delimiter=",", comments="#")
    cams = read_tum(out / "groundtruth.txt")
    rows = np.searchsorted(gt[:, 0], np.rint(cams.timestamps * 1e9))
    T_cam_imu = np.asarray(imu_cfg.T_cam_imu).reshape(4, 4)
    np.testing.assert_allclose(gt[rows, 1:4], (cams.T_world_cam @ T_cam_imu)[:, :3, 3], atol=1e-8)
    np.testing.assert_array_equal(gt[:, 8:11], sim.v_world)
    np.testing.assert_array_equal(gt[:, 11:14], sim.gyro_bias)


def test_noise_statistics():
    """Measured minus exact minus the true bias is white noise of std density / sqrt(dt); the bias
    increments have std random_walk * sqrt(dt). 3 sigma bands of a sample std from N samples:
    relative std 1 / sqrt(2 N) (N = 3 axes x ~2200 samples: 0.9 %, band 2.6 %)."""
    cfg = SyntheticImuConfig(seed=11)
    sim = simulate_imu(SyntheticConfig(n_frames=300), cfg)
    dt = 1.0 / cfg.rate_hz
    n = sim.gyro.size
    band = 3.0 / np.sqrt(2 * n)
    checks = [
        (sim.gyro - sim.gyro_true - sim.gyro_bias, cfg.gyro_noise_density / np.sqrt(dt)),
        (sim.accel - sim.accel_true - sim.accel_bias, cfg.accel_noise_density / np.sqrt(dt)),
        (np.diff(sim.gyro_bias, axis=0), cfg.gyro_random_walk * np.sqrt(dt)),
        (np.diff(sim.accel_bias, axis=0), cfg.accel_random_walk * np.sqrt(dt)),
    ]
    for x, sigma in checks:
        assert np.std(x) / sigma == pytest.approx(1.0, abs=band)
    np.testing.assert_allclose(sim.gyro_bias[0], cfg.gyro_bias)


def test_seeded_and_exact_when_noise_free():
    a = simulate_imu(SMALL, SyntheticImuConfig(seed=1))
    b = simulate_imu(SMALL, SyntheticImuConfig(seed=1))
    c = simulate_imu(SMALL, SyntheticImuConfig(seed=2))
    np.testing.assert_array_equal(a.gyro, b.gyro)
    assert not np.array_equal(a.gyro, c.gyro)
    exact = simulate_imu(SMALL, SyntheticImuConfig(noise=False))
    np.testing.assert_allclose(exact.gyro, exact.gyro_true + np.asarray(SyntheticImuConfig().gyro_bias), atol=1e-15)
    # at any time the specific force minus the body-frame acceleration is the body-frame gravity
    # reaction: |f - R^T a| = g, to the central difference's error dt^2 / 6 |v'''| <= 1e-4 m/s^2
    # (|v'''| <= 25 m/s^4 on this fast path; measured 7e-7)
    R = exact.T_world_imu[:, :3, :3]
    acc = np.gradient(exact.v_world, exact.timestamps, axis=0)
    react = exact.accel_true - np.einsum("nji,nj->ni", R, acc)
    assert np.abs(np.linalg.norm(react[2:-2], axis=1) - 9.81).max() < 0.005**2 / 6 * 25
