"""TUM RGB-D reader on the staged fr1/desk and fr3/cabinet clips, and the stereo/camera extensions."""
from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from vslam.datasets import open_dataset
from vslam.datasets.base import read_timestamped_list
from vslam.datasets.tum import TUM_PRESETS, TumDataset, tum_preset_from_name
from vslam.errors import CalibrationError, DatasetError
from vslam.trajectory import associate_timestamps

pytestmark = pytest.mark.shared


def test_fr1_desk_counts_intrinsics_and_depth(shared_data):
    root = shared_data / "tum_rgbd_freiburg1_desk_9frames"
    ds = open_dataset(root)
    assert isinstance(ds, TumDataset) and ds.kind == "tum"
    assert ds.sensor == "rgbd" and set(ds.sensors) == {"mono", "rgbd"}
    assert len(ds) == 9
    cam = ds.camera
    assert (cam.fx, cam.fy, cam.cx, cam.cy) == (517.306408, 516.469215, 318.643040, 255.313989)
    assert cam.dist == (0.262383, -0.953104, -0.005358, 0.002628, 1.163314)
    assert (cam.width, cam.height) == (640, 480)
    assert ds.timestamps[0] == pytest.approx(1305031453.359684, abs=1e-6)
    assert ds.timestamps[-1] == pytest.approx(1305031453.627706, abs=1e-6)
    frames = list(ds)
    assert [f.index for f in frames] == list(range(9))
    f = frames[3]
    assert f.image.shape == (480, 640, 3) and f.image.dtype == np.uint8
    raw = cv2.imread(str(root / "depth" / "1305031453.473352.png"), cv2.IMREAD_UNCHANGED)
    assert raw.dtype == np.uint16
    assert f.depth.dtype == np.float32
    np.testing.assert_array_equal(f.depth, raw.astype(np.float32) / np.float32(5000.0))
    valid = f.depth[f.depth > 0]
    assert valid.size > 0.5 * f.depth.size
    assert 0.5 < np.median(valid) < 3.0  # a desk seen from ~1 m
    assert ds.skipped == 0


def test_fr1_association_matches_associate_txt(shared_data):
    """Our associate.py re-implementation pairs rgb.txt/depth.txt exactly like the shipped file."""
    root = shared_data / "tum_rgbd_freiburg1_desk_9frames"
    t_rgb, _ = read_timestamped_list(root / "rgb.txt", "rgb")
    t_dep, _ = read_timestamped_list(root / "depth.txt", "depth")
    pairs = np.column_stack(associate_timestamps(t_rgb, t_dep, 0.02))
    t_a, rows = read_timestamped_list(root / "associate.txt", "assoc", 4)
    np.testing.assert_array_equal(t_rgb[pairs[:, 0]], t_a)
    np.testing.assert_array_equal(t_dep[pairs[:, 1]], [float(r[1]) for r in rows])


def test_fr1_ground_truth_is_interpolated_from_100hz(shared_data):
    root = shared_data / "tum_rgbd_freiburg1_desk_9frames"
    ds = open_dataset(root, sensor="mono")
    gt = ds.ground_truth()
    assert gt is not None and len(gt) == 9
    np.testing.assert_allclose(gt.timestamps, ds.timestamps)
    raw = np.loadtxt(root / "groundtruth.txt")
    i = 5
    t = ds.timestamps[i]
    k = np.searchsorted(raw[:, 0], t)
    t0, t1 = raw[k - 1, 0], raw[k, 0]
    assert t0 < t < t1 and t1 - t0 < 0.02
    a = (t - t0) / (t1 - t0)
    p = (1 - a) * raw[k - 1, 1:4] + a * raw[k, 1:4]
    R = Slerp([t0, t1], Rotation.from_quat(raw[k - 1 : k + 1, 4:8]))([t]).as_matrix()[0]
    T = ds[i].T_world_cam
    np.testing.assert_allclose(T[:3, 3], p, atol=1e-9)
    np.testing.assert_allclose(T[:3, :3], R, atol=1e-9)
    np.testing.assert_allclose(gt.T_world_cam[i], T, atol=1e-12)


def test_fr3_cabinet_keyframes(shared_data):
    root = shared_data / "tum_fr3_cabinet_keyframes58"
    ds = open_dataset(root)
    assert len(ds) == 58 and ds.sensor == "rgbd"
    cam = ds.camera
    assert (cam.fx, cam.fy, cam.cx, cam.cy) == (535.4, 539.2, 320.1, 247.6) and not cam.is_distorted
    assert ds.timestamps[-1] - ds.timestamps[0] == pytest.approx(38.4, abs=0.1)
    gt = ds.ground_truth()
    assert len(gt) == 58  # GT sampled exactly at the keyframe timestamps
    raw = np.loadtxt(root / "groundtruth.txt")
    f = ds[56]
    np.testing.assert_allclose(f.T_world_cam[:3, 3], raw[56, 1:4], atol=1e-12)
    np.testing.assert_allclose(f.T_world_cam[:3, :3], Rotation.from_quat(raw[56, 4:8]).as_matrix(), atol=1e-12)
    # README: keyframe 56 is 0.28 m from keyframe 0 (the loop)
    assert np.linalg.norm(gt.positions[56] - gt.positions[0]) == pytest.approx(0.28, abs=0.01)
    valid = f.depth[f.depth > 0]
    assert 0.3 < np.median(valid) < 5.0
    assert f.image.shape == (480, 640, 3)


def test_preset_names():
    assert tum_preset_from_name("rgbd_dataset_freiburg1_desk") == 1
    assert tum_preset_from_name("tum_fr3_cabinet_keyframes58") == 3
    assert tum_preset_from_name("fr2_xyz") == 2
    assert tum_preset_from_name("fr10_thing") is None
    assert tum_preset_from_name("my_sequence") is None
    assert TUM_PRESETS[2].fx == 520.908620 and TUM_PRESETS[2].dist[4] == 0.917205


def test_camera_yaml_and_stereo_extension(tmp_path, make_tum):
    root = make_tum(
        tmp_path / "synthetic_fr1",  # camera.yaml must win over the fr1 preset in the name
        right=True,
        camera_yaml="fx: 50\nfy: 51\ncx: 31.5\ncy: 23.5\nwidth: 64\nheight: 48\nbaseline: 0.1\n"
        "depth_scale: 1000\nfps: 15\ndist: [0.1, 0, 0, 0, 0]\n",
    )
    ds = open_dataset(root)
    assert set(ds.sensors) == {"mono", "stereo", "rgbd"} and ds.sensor == "rgbd"
    assert (ds.camera.fx, ds.camera.fy, ds.camera.baseline, ds.frame_rate) == (50, 51, 0.1, 15)
    assert ds.camera.dist == (0.1, 0, 0, 0, 0)
    f = ds[2]
    raw = cv2.imread(str(root / "depth" / f"{1000 + 2 / 30 + 0.004:.6f}.png"), cv2.IMREAD_UNCHANGED)
    np.testing.assert_array_equal(f.depth, raw.astype(np.float32) / np.float32(1000))
    st = open_dataset(root, sensor="stereo")
    fs = st[4]
    assert fs.image_right is not None and fs.depth is None
    np.testing.assert_array_equal(fs.image_right, cv2.imread(str(root / "right" / f"{1000 + 4 / 30:.6f}.png")))
    mono = open_dataset(root, sensor="mono")
    fm = mono[0]
    assert fm.depth is None and fm.image_right is None
    # GT at 100 Hz moving 0.1 m per sample along x -> x = 10 * (t - t0 + 0.05)
    gt = mono.ground_truth()
    np.testing.assert_allclose(gt.positions[:, 0], 10 * (mono.timestamps - 1000 + 0.05), atol=2e-3)


def test_stereo_without_baseline_is_a_calibration_error(tmp_path, make_tum):
    root = make_tum(tmp_path / "seq", right=True)
    with pytest.raises(CalibrationError, match="baseline"):
        open_dataset(root, sensor="stereo")


def test_sensor_not_available(tmp_path, make_tum):
    root = make_tum(tmp_path / "seq", depth=False)
    ds = open_dataset(root)
    assert ds.sensors == ("mono",) and ds.sensor == "mono"
    with pytest.raises(DatasetError, match="depth.txt"):
        open_dataset(root, sensor="rgbd")
    with pytest.raises(DatasetError, match="right.txt"):
        open_dataset(root, sensor="stereo")
    with pytest.raises(DatasetError, match="unknown sensor"):
        open_dataset(root, sensor="lidar")


def test_frames_outside_ground_truth_have_no_pose(tmp_path, make_tum):
    root = make_tum(tmp_path / "seq", n=12)
    lines = (root / "groundtruth.txt").read_text().splitlines()
    (root / "groundtruth.txt").write_text("\n".join(lines[:25]) + "\n")  # GT ends at t0 + 0.19 s
    ds = open_dataset(root)
    covered = [f.T_world_cam is not None for f in ds]
    assert covered == [t <= 1000.19 for t in ds.timestamps]
    assert sum(covered) == 6 and len(ds.ground_truth()) == 6
    (root / "groundtruth.txt").unlink()
    ds = open_dataset(root)
    assert ds.ground_truth() is None and ds[0].T_world_cam is None


def test_skipped_counts_distinct_frames(tmp_path, make_tum):
    root = make_tum(tmp_path / "seq", n=12)
    sorted((root / "rgb").iterdir())[4].write_bytes(b"garbage")
    ds = open_dataset(root)
    assert len(list(ds)) == 11 and len(list(ds)) == 11
    assert ds.skipped == 1
