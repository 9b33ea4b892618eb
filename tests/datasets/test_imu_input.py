"""IMU input: the EuRoC-CSV reader, the calibration readers (EuRoC, Kalibr, ORB-SLAM3), and one
clear error (or a warning where a run can go on) for each kind of bad IMU input."""
from __future__ import annotations

import logging
import shutil
from pathlib import Path

import numpy as np
import pytest

from vslam.datasets import open_dataset
from vslam.datasets.imu import load_imu_csv, read_imu_calibration
from vslam.errors import CalibrationError, DatasetError
from vslam.inertial import DEFAULT_NOISE

HEADER = "#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],a_RS_S_x [m s^-2]," \
         "a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]\n"
T0_NS = 1_403_636_590_163_555_584


def write_csv(path: Path, ns: np.ndarray, gyro: np.ndarray, accel: np.ndarray, header: str = HEADER) -> Path:
    rows = "".join(f"{t}," + ",".join(f"{v:.9g}" for v in np.r_[g, a]) + "\n" for t, g, a in zip(ns, gyro, accel))
    path.write_text(header + rows)
    return path


def steady(n: int = 400, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """200 Hz samples of a gently moving IMU (rad/s, m/s^2)."""
    rng = np.random.default_rng(seed)
    ns = T0_NS + np.arange(n, dtype=np.int64) * 5_000_000
    t = np.arange(n) * 0.005
    gyro = np.stack([0.3 * np.sin(t), 0.2 * np.cos(2 * t), 0.1 + 0 * t], axis=1) + 1e-3 * rng.standard_normal((n, 3))
    accel = np.tile([0.2, 0.1, 9.8], (n, 1)) + 0.5 * np.stack([np.sin(3 * t), np.cos(t), 0 * t], axis=1)
    return ns, gyro, accel


# -- samples ------------------------------------------------------------------------------------
def test_reads_euroc_csv(tmp_path):
    ns, g, a = steady()
    imu = load_imu_csv(write_csv(tmp_path / "imu.csv", ns, g, a))
    assert len(imu) == 400 and imu.source.endswith("imu.csv")
    np.testing.assert_allclose(imu.timestamps, ns * 1e-9)
    np.testing.assert_allclose(imu.gyro, g, rtol=1e-8)
    np.testing.assert_allclose(imu.accel, a, rtol=1e-8)


def test_reads_decimal_seconds_and_plain_header(tmp_path):
    ns, g, a = steady(50)
    text = "timestamp,wx,wy,wz,ax,ay,az\n" + "".join(
        f"{t * 1e-9:.6f}," + ",".join(map(str, np.r_[gi, ai])) + "\n" for t, gi, ai in zip(ns, g, a))
    (tmp_path / "imu.csv").write_text(text)
    imu = load_imu_csv(tmp_path / "imu.csv")
    np.testing.assert_allclose(imu.timestamps, ns * 1e-9, atol=1e-6)  # the file has microseconds


def test_missing_file(tmp_path):
    with pytest.raises(DatasetError, match=r"nothere\.csv: IMU file not found"):
        load_imu_csv(tmp_path / "nothere.csv")


def test_empty_file(tmp_path):
    (tmp_path / "imu.csv").write_text(HEADER)
    with pytest.raises(DatasetError, match=r"imu\.csv: no IMU samples"):
        load_imu_csv(tmp_path / "imu.csv")


def test_malformed_line_names_the_line(tmp_path):
    ns, g, a = steady(10)
    path = write_csv(tmp_path / "imu.csv", ns, g, a)
    lines = path.read_text().splitlines()
    lines[4] = lines[4].replace(",", ",x", 1)
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(DatasetError, match=r"imu\.csv:5: not a number"):
        load_imu_csv(path)
    path.write_text(HEADER + "1,2,3\n")
    with pytest.raises(DatasetError, match=r"imu\.csv:2: expected 7 columns"):
        load_imu_csv(path)


def test_unsorted_stamps(tmp_path):
    ns, g, a = steady(20)
    ns[[7, 8]] = ns[[8, 7]]
    with pytest.raises(DatasetError, match=r"imu\.csv: timestamps are not sorted \(sample 9 .*sort the file"):
        load_imu_csv(write_csv(tmp_path / "imu.csv", ns, g, a))


def test_duplicate_stamps(tmp_path):
    ns, g, a = steady(20)
    ns[5] = ns[4]
    with pytest.raises(DatasetError, match=r"imu\.csv: duplicate timestamp at samples 5 and 6.*remove one"):
        load_imu_csv(write_csv(tmp_path / "imu.csv", ns, g, a))


def test_gap_is_a_warning(tmp_path, caplog):
    ns, g, a = steady(40)
    ns[20:] += 80_000_000  # 85 ms between samples 20 and 21
    with caplog.at_level(logging.WARNING, logger="vslam.inertial"):
        imu = load_imu_csv(write_csv(tmp_path / "imu.csv", ns, g, a))
    assert len(imu) == 40
    msgs = [r.getMessage() for r in caplog.records]
    assert any("imu.csv" in m and "1 gap(s) over 50 ms" in m and "0.085 s" in m for m in msgs), msgs


@pytest.mark.shared
def test_degrees_instead_of_radians_fast_motion(tmp_path, shared_data):
    """Real MH_01 (peaks at 0.95 rad/s) passes; the same samples in deg/s (54 'rad/s') fail."""
    src = shared_data / "euroc_mh01_vi_80" / "mav0" / "imu0" / "data.csv"
    imu = load_imu_csv(src)
    path = write_csv(tmp_path / "imu.csv", np.rint(imu.timestamps * 1e9).astype(np.int64),
                     np.degrees(imu.gyro), imu.accel)
    with pytest.raises(DatasetError, match=r"imu\.csv: the gyro looks like degrees/s.*multiply by pi/180"):
        load_imu_csv(path)


@pytest.mark.shared
def test_degrees_instead_of_radians_at_rest(tmp_path, shared_data):
    """Real V1_01 at rest (a 0.08 rad/s bias) passes; in deg/s its 4.4 'rad/s' with a still
    accelerometer cannot be a rate in rad/s."""
    src = shared_data / "euroc_V1_01_easy_40frames" / "mav0" / "imu0" / "data.csv"
    imu = load_imu_csv(src)
    path = write_csv(tmp_path / "imu.csv", np.rint(imu.timestamps * 1e9).astype(np.int64),
                     np.degrees(imu.gyro), imu.accel)
    with pytest.raises(DatasetError, match=r"degrees/s.*accelerometer is still"):
        load_imu_csv(path)


# -- EuRoC folders ------------------------------------------------------------------------------
@pytest.fixture
def euroc_copy(tmp_path, shared_data):
    """A EuRoC V1_01 folder whose cameras link to the shared clip and whose imu0/ is a copy."""
    src = shared_data / "euroc_V1_01_easy_40frames" / "mav0"
    mav0 = tmp_path / "seq" / "mav0"
    mav0.mkdir(parents=True)
    for cam in ("cam0", "cam1"):
        (mav0 / cam).symlink_to(src / cam, target_is_directory=True)
    shutil.copytree(src / "imu0", mav0 / "imu0")
    return mav0


@pytest.mark.shared
def test_euroc_finds_imu(euroc_copy):
    ds = open_dataset(euroc_copy.parent)
    assert len(ds.imu) == 691 and ds.imu_calibration.gyro_noise_density == 1.6968e-04
    np.testing.assert_allclose(ds.imu_calibration.T_imu_cam, ds.T_body_cam0)


@pytest.mark.shared
def test_euroc_without_imu_has_none(euroc_copy):
    shutil.rmtree(euroc_copy / "imu0")
    ds = open_dataset(euroc_copy.parent)
    assert ds.imu is None and ds.imu_calibration is None


@pytest.mark.shared
def test_no_overlap_with_images(euroc_copy):
    imu = load_imu_csv(euroc_copy / "imu0" / "data.csv")
    ns = np.rint(imu.timestamps * 1e9).astype(np.int64) - 3_600_000_000_000  # an hour early
    write_csv(euroc_copy / "imu0" / "data.csv", ns, imu.gyro, imu.accel)
    ds = open_dataset(euroc_copy.parent)
    assert ds[0].image is not None  # frames are unaffected: the IMU is read on first use
    with pytest.raises(DatasetError, match=r"imu0/data\.csv: the IMU samples .* do not overlap the images"):
        _ = ds.imu


@pytest.mark.shared
def test_partial_overlap_is_a_warning(euroc_copy, caplog):
    imu = load_imu_csv(euroc_copy / "imu0" / "data.csv")
    keep = imu.timestamps < 1403715275.5  # the images run to 1403715276.26
    write_csv(euroc_copy / "imu0" / "data.csv", np.rint(imu.timestamps[keep] * 1e9).astype(np.int64),
              imu.gyro[keep], imu.accel[keep])
    with caplog.at_level(logging.WARNING, logger="vslam.inertial"):
        assert len(open_dataset(euroc_copy.parent).imu) == int(keep.sum())
    assert any("frames outside have no IMU" in r.getMessage() for r in caplog.records)


@pytest.mark.shared
def test_non_rigid_T_BS(euroc_copy):
    yaml_path = euroc_copy / "imu0" / "sensor.yaml"
    text = yaml_path.read_text()
    assert "data: [1.0, 0.0, 0.0, 0.0," in text
    yaml_path.write_text(text.replace("data: [1.0, 0.0, 0.0, 0.0,", "data: [1.2, 0.0, 0.0, 0.0,"))
    ds = open_dataset(euroc_copy.parent)
    with pytest.raises(CalibrationError, match=r"imu0/sensor\.yaml .*T_BS is not a rigid transform"):
        _ = ds.imu_calibration


@pytest.mark.shared
def test_missing_noise_values_take_defaults(euroc_copy, caplog):
    yaml_path = euroc_copy / "imu0" / "sensor.yaml"
    lines = [ln for ln in yaml_path.read_text().splitlines() if not ln.startswith("gyroscope_random_walk")]
    yaml_path.write_text("\n".join(lines) + "\n")
    with caplog.at_level(logging.WARNING, logger="vslam.inertial"):
        calib = open_dataset(euroc_copy.parent).imu_calibration
    assert calib.defaulted == ("gyro_random_walk",)
    assert calib.gyro_random_walk == DEFAULT_NOISE["gyro_random_walk"] and calib.accel_random_walk == 3.0e-3
    assert any("no gyro_random_walk given" in r.getMessage() for r in caplog.records)


# -- calibration files of other tools -----------------------------------------------------------
T_CAM_IMU = [[0.0148655429818, 0.999557249008, -0.0257744366974, 0.0652229833166],
             [-0.999880929698, 0.0149672133247, 0.00375618835797, -0.0207063834070],
             [0.00414029679422, 0.025715529948, 0.999660727178, -0.00805460246002],
             [0.0, 0.0, 0.0, 1.0]]


def test_kalibr_camchain_and_imu_yaml(tmp_path):
    chain = tmp_path / "camchain-imucam.yaml"
    chain.write_text("cam0:\n  T_cam_imu:\n" + "".join(f"  - {row}\n" for row in T_CAM_IMU)
                     + "  timeshift_cam_imu: -0.0021\n  intrinsics: [458.6, 457.3, 367.2, 248.4]\n")
    imu_yaml = tmp_path / "imu.yaml"
    imu_yaml.write_text("accelerometer_noise_density: 1.86e-03\naccelerometer_random_walk: 4.33e-04\n"
                        "gyroscope_noise_density: 1.87e-04\ngyroscope_random_walk: 2.66e-05\n"
                        "rostopic: /imu0\nupdate_rate: 200.0\n")
    calib = read_imu_calibration([chain, imu_yaml])
    np.testing.assert_allclose(calib.T_cam_imu, T_CAM_IMU, atol=1e-12)
    assert calib.time_offset == -0.0021 and calib.accel_random_walk == 4.33e-04 and calib.defaulted == ()
    # Kalibr's results file nests the values under imu0
    nested = tmp_path / "imu-results.yaml"
    nested.write_text("imu0:\n  gyroscope_noise_density: 1.0e-4\n  update_rate: 400\n")
    calib = read_imu_calibration([chain, nested])
    assert calib.gyro_noise_density == 1.0e-4 and calib.rate_hz == 400
    assert set(calib.defaulted) == {"gyro_random_walk", "accel_noise_density", "accel_random_walk"}


def test_orbslam3_settings(tmp_path):
    T_imu_cam = np.linalg.inv(np.array(T_CAM_IMU))
    settings = tmp_path / "EuRoC.yaml"
    settings.write_text(
        "%YAML:1.0\nCamera.type: \"PinHole\"\nCamera1.fx: 458.654\n"
        "IMU.T_b_c1: !!opencv-matrix\n   rows: 4\n   cols: 4\n   dt: f\n   data: ["
        + ", ".join(f"{v:.9f}" for v in T_imu_cam.ravel()) + "]\n"
        "IMU.NoiseGyro: 1.7e-4\nIMU.NoiseAcc: 2.0e-3\nIMU.GyroWalk: 1.9393e-05\nIMU.AccWalk: 3.0e-03\n"
        "IMU.Frequency: 200.0\n")
    calib = read_imu_calibration(settings)
    np.testing.assert_allclose(calib.T_imu_cam, T_imu_cam, atol=1e-8)
    assert calib.gyro_noise_density == 1.7e-4 and calib.rate_hz == 200 and calib.defaulted == ()


def test_orbslam3_non_rigid(tmp_path):
    settings = tmp_path / "s.yaml"
    settings.write_text("IMU.T_b_c1: !!opencv-matrix\n  rows: 4\n  cols: 4\n  dt: f\n"
                        "  data: [1, 0.3, 0, 0,  0, 1, 0, 0,  0, 0, 1, 0,  0, 0, 0, 1]\n")
    with pytest.raises(CalibrationError, match=r"s\.yaml \(ORB-SLAM3 settings\): IMU\.T_b_c1 is not a rigid"):
        read_imu_calibration(settings)


def test_calibration_errors(tmp_path):
    with pytest.raises(CalibrationError, match="IMU calibration file not found"):
        read_imu_calibration(tmp_path / "none.yaml")
    (tmp_path / "x.yaml").write_text("fx: 500\n")
    with pytest.raises(CalibrationError, match=r"x\.yaml: unrecognised IMU calibration"):
        read_imu_calibration(tmp_path / "x.yaml")
    (tmp_path / "imu.yaml").write_text("gyroscope_noise_density: 1.0e-4\n")
    with pytest.raises(CalibrationError, match="no camera-IMU extrinsics"):
        read_imu_calibration(tmp_path / "imu.yaml")
    (tmp_path / "bad.yaml").write_text("gyroscope_noise_density: fast\n")
    with pytest.raises(CalibrationError, match=r"'gyroscope_noise_density' = 'fast'"):
        read_imu_calibration(tmp_path / "bad.yaml")
