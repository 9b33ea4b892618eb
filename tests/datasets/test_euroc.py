"""EuRoC reader: staged V1_01 clip, stereo rectification, GT frame conversions."""
from __future__ import annotations

import shutil

import cv2
import numpy as np
import pytest

from vslam.datasets import open_dataset
from vslam.datasets.euroc import EurocDataset, read_euroc_sensor
from vslam.errors import CalibrationError, DatasetError

pytestmark = pytest.mark.shared


@pytest.fixture(scope="module")
def euroc_root(shared_data):
    return shared_data / "euroc_V1_01_easy_40frames"


def test_stereo_rectified(euroc_root):
    ds = open_dataset(euroc_root)
    assert isinstance(ds, EurocDataset) and ds.sensor == "stereo" and len(ds) == 40
    assert ds.frame_rate == 20
    cam = ds.camera
    assert not cam.is_distorted and (cam.width, cam.height) == (752, 480)
    assert cam.baseline == pytest.approx(0.110, abs=0.002)
    # the baseline equals the distance between the two camera centres from T_BS
    d = np.linalg.norm(ds.T_body_cam1[:3, 3] - ds.T_body_cam0[:3, 3])
    assert cam.baseline == pytest.approx(d, rel=1e-6)
    np.testing.assert_allclose(ds.timestamps[[0, -1]], [1403715274.312143104, 1403715276.262142976])
    f = ds[20]
    assert f.image.shape == (480, 752) and f.image_right.shape == (480, 752)
    # rectified: ORB matches between left and right lie on the same row, with positive disparity
    orb = cv2.ORB_create(1000)
    k1, d1 = orb.detectAndCompute(f.image, None)
    k2, d2 = orb.detectAndCompute(f.image_right, None)
    matches = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True).match(d1, d2)
    p1 = np.array([k1[m.queryIdx].pt for m in matches])
    p2 = np.array([k2[m.trainIdx].pt for m in matches])
    good = np.abs(p1[:, 1] - p2[:, 1]) < 3
    assert good.sum() > 100
    assert np.median(np.abs(p1[good, 1] - p2[good, 1])) < 0.6
    assert np.median(p1[good, 0] - p2[good, 0]) > 0


def test_gt_of_rectified_left_camera(euroc_root):
    ds = open_dataset(euroc_root, sensor="stereo")
    mono = open_dataset(euroc_root / "mav0", sensor="mono")
    raw = np.loadtxt(euroc_root / "groundtruth_cam0_tum.txt")
    k = np.argmin(np.abs(raw[:, 0] - ds.timestamps[7]))
    from scipy.spatial.transform import Rotation

    R_world_cam0 = Rotation.from_quat(raw[k, 4:8]).as_matrix()
    T_m = mono[7].T_world_cam
    np.testing.assert_allclose(T_m[:3, 3], raw[k, 1:4], atol=1e-9)
    np.testing.assert_allclose(T_m[:3, :3], R_world_cam0, atol=1e-9)
    T_s = ds[7].T_world_cam
    np.testing.assert_allclose(T_s[:3, 3], raw[k, 1:4], atol=1e-9)  # same optical centre
    np.testing.assert_allclose(T_s[:3, :3], R_world_cam0 @ ds.R_rect_cam0.T, atol=1e-9)
    assert len(ds.ground_truth()) == 40 and len(mono.ground_truth()) == 40


def test_mono_exposes_distorted_cam0(euroc_root):
    ds = open_dataset(euroc_root, sensor="mono")
    cam = ds.camera
    assert (cam.fx, cam.fy, cam.cx, cam.cy) == (458.654, 457.296, 367.215, 248.375)
    assert cam.dist[:4] == (-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05)
    f = ds[0]
    assert f.image_right is None
    np.testing.assert_array_equal(
        f.image, cv2.imread(str(euroc_root / "mav0/cam0/data/1403715274312143104.png"), cv2.IMREAD_GRAYSCALE)
    )
    with pytest.raises(DatasetError, match="no depth"):
        open_dataset(euroc_root, sensor="rgbd")


def test_gt_sources_agree(euroc_root, tmp_path):
    """The body-frame CSV (x T_BS) and the ORB-SLAM3 conjugated file give the cam0 TUM GT."""
    ref = open_dataset(euroc_root, sensor="mono").ground_truth()
    seq = tmp_path / "V101"
    cam0 = seq / "mav0" / "cam0"
    cam0.mkdir(parents=True)
    for name in ("sensor.yaml", "data.csv"):
        shutil.copy(euroc_root / "mav0" / "cam0" / name, cam0)
    (cam0 / "data").symlink_to(euroc_root / "mav0" / "cam0" / "data")
    # ORB-SLAM3 style only
    shutil.copy(euroc_root / "V101_GT_left_cam.txt", seq)
    ds = EurocDataset(seq, sensor="mono")
    orb = ds.ground_truth()
    np.testing.assert_allclose(orb.T_world_cam, ref.T_world_cam, atol=1e-6)
    # body frame CSV (written from groundtruth_body_tum.txt) wins over the ORB file
    body = np.loadtxt(euroc_root / "groundtruth_body_tum.txt")
    (seq / "mav0" / "state_groundtruth_estimate0").mkdir()
    rows = [f"{int(round(r[0] * 1e9))},{r[1]},{r[2]},{r[3]},{r[7]},{r[4]},{r[5]},{r[6]}" for r in body]
    (seq / "mav0" / "state_groundtruth_estimate0" / "data.csv").write_text("#t,x,y,z,qw,qx,qy,qz\n" + "\n".join(rows))
    ds = EurocDataset(seq, sensor="mono")
    np.testing.assert_allclose(ds.ground_truth().T_world_cam, ref.T_world_cam, atol=1e-6)


def test_bad_sensor_yaml(euroc_root, tmp_path):
    y = tmp_path / "sensor.yaml"
    text = (euroc_root / "mav0" / "cam0" / "sensor.yaml").read_text()
    y.write_text(text.replace("intrinsics:", "intrinsix:"))
    with pytest.raises(CalibrationError, match="missing 'intrinsics'"):
        read_euroc_sensor(y)
    y.write_text(text.replace("[752, 480]", "[752, abc]"))
    with pytest.raises(CalibrationError, match="malformed"):
        read_euroc_sensor(y)
    y.write_text("T_BS: [1, 2\n")
    with pytest.raises(CalibrationError, match="not valid YAML"):
        read_euroc_sensor(y)
