"""Calibration files of other tools: format detection, values, errors naming format and field."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from vslam.datasets import open_dataset
from vslam.datasets.calibration import Rectifier, read_camera_file
from vslam.errors import CalibrationError

K = np.array([[520.5, 0, 321.25], [0, 519.75, 241.5], [0, 0, 1]])
D = np.array([0.11, -0.22, 0.001, -0.002, 0.05])


def _check(cal, fmt, dist=tuple(D), size=(640, 480), model="radtan"):
    c = cal.camera
    assert cal.format == fmt and cal.model == model
    np.testing.assert_allclose([c.fx, c.fy, c.cx, c.cy], [520.5, 519.75, 321.25, 241.5])
    assert (c.width, c.height) == size
    np.testing.assert_allclose(c.dist, dist, atol=1e-12)


@pytest.mark.parametrize("suffix", [".yaml", ".xml"])
def test_opencv_filestorage_written_by_opencv(tmp_path, suffix):
    path = tmp_path / f"calib{suffix}"
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", 640)
    fs.write("image_height", 480)
    fs.write("camera_matrix", K)
    fs.write("distortion_coefficients", D.reshape(5, 1))
    fs.write("avg_reprojection_error", 0.3)
    fs.release()
    _check(read_camera_file(path), "opencv")


def test_ros_camera_info(tmp_path):
    path = tmp_path / "camera_info.yaml"
    path.write_text(
        "image_width: 640\nimage_height: 480\ncamera_name: head\n"
        f"camera_matrix:\n  rows: 3\n  cols: 3\n  data: {K.ravel().tolist()}\n"
        "distortion_model: plumb_bob\n"
        f"distortion_coefficients:\n  rows: 1\n  cols: 5\n  data: {D.tolist()}\n"
        "rectification_matrix:\n  rows: 3\n  cols: 3\n  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]\n"
        "projection_matrix:\n  rows: 3\n  cols: 4\n  data: [520.5, 0, 321.25, 0, 0, 519.75, 241.5, 0, 0, 0, 1, 0]\n"
    )
    _check(read_camera_file(path), "ros")
    path.write_text(path.read_text().replace("plumb_bob", "equidistant").replace(
        f"rows: 1\n  cols: 5\n  data: {D.tolist()}", "rows: 1\n  cols: 4\n  data: [0.1, 0.01, -0.002, 0.0003]"))
    _check(read_camera_file(path), "ros", dist=(0.1, 0.01, -0.002, 0.0003), model="equidistant")


def test_orbslam2_and_orbslam3(tmp_path):
    orb2 = tmp_path / "TUM1.yaml"
    orb2.write_text(
        "%YAML:1.0\nCamera.fx: 520.5\nCamera.fy: 519.75\nCamera.cx: 321.25\nCamera.cy: 241.5\n"
        "Camera.k1: 0.11\nCamera.k2: -0.22\nCamera.p1: 0.001\nCamera.p2: -0.002\nCamera.k3: 0.05\n"
        "Camera.width: 640\nCamera.height: 480\nCamera.fps: 30.0\nCamera.bf: 40.0\nDepthMapFactor: 5000.0\n"
    )
    cal = read_camera_file(orb2)
    _check(cal, "orbslam2")
    assert cal.extras == {"depth_scale": 5000.0, "fps": 30.0}
    assert cal.camera.baseline == pytest.approx(40.0 / 520.5)
    orb3 = tmp_path / "orb3.yaml"
    orb3.write_text(
        '%YAML:1.0\nFile.version: "1.0"\nCamera.type: "PinHole"\n'
        "Camera1.fx: 520.5\nCamera1.fy: 519.75\nCamera1.cx: 321.25\nCamera1.cy: 241.5\n"
        "Camera1.k1: 0.11\nCamera1.k2: -0.22\nCamera1.p1: 0.001\nCamera1.p2: -0.002\nCamera1.k3: 0.05\n"
        "Camera.width: 640\nCamera.height: 480\nCamera.fps: 20\nRGBD.DepthMapFactor: 1000.0\n"
    )
    cal = read_camera_file(orb3)
    _check(cal, "orbslam3")
    assert cal.extras == {"fps": 20.0, "depth_scale": 1000.0} and cal.right is None
    # stereo rig (EuRoC-like): Camera2 + Stereo.T_c1_c2 -> needs rectification, baseline from T
    stereo = orb3.read_text().replace("Camera.fps: 20", "Camera.fps: 20\n" + (
        "Camera2.fx: 520.5\nCamera2.fy: 519.75\nCamera2.cx: 321.25\nCamera2.cy: 241.5\n"
        "Stereo.T_c1_c2: !!opencv-matrix\n  rows: 4\n  cols: 4\n  dt: f\n"
        "  data: [1, 0, 0, 0.11, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]\n"))
    (tmp_path / "s.yaml").write_text(stereo)
    cal = read_camera_file(tmp_path / "s.yaml")
    assert cal.needs_remap and cal.T_right_left[0, 3] == pytest.approx(-0.11)
    rect = Rectifier(cal)
    assert rect.camera.baseline == pytest.approx(0.11, rel=1e-6) and not rect.camera.is_distorted
    missing = tmp_path / "m.yaml"
    missing.write_text(orb3.read_text().replace("Camera1.fy: 519.75\n", ""))
    with pytest.raises(CalibrationError, match=r"detected format: ORB-SLAM3 v1.0 settings, but field 'Camera1.fy' is missing"):
        read_camera_file(missing)
    missing.write_text(orb2.read_text().replace("Camera.cy: 241.5\n", ""))
    with pytest.raises(CalibrationError, match=r"detected format: ORB-SLAM2 settings, but field 'Camera.cy' is missing"):
        read_camera_file(missing)


def test_kalibr_camchain_mono_stereo_and_fisheye(tmp_path):
    cam0 = ("cam0:\n  camera_model: pinhole\n  intrinsics: [520.5, 519.75, 321.25, 241.5]\n"
            "  distortion_model: radtan\n  distortion_coeffs: [0.11, -0.22, 0.001, -0.002]\n"
            "  resolution: [640, 480]\n  rostopic: /cam0/image_raw\n")
    path = tmp_path / "camchain.yaml"
    path.write_text(cam0)
    _check(read_camera_file(path), "kalibr", dist=(0.11, -0.22, 0.001, -0.002, 0.0))
    R = cv2.Rodrigues(np.array([0.0, 0.0, 0.0141]))[0]
    rows = np.hstack([R, [[-0.1101], [0.0004], [0.0008]]])
    t_lines = "".join(f"  - [{', '.join(f'{v:.9f}' for v in r)}]\n" for r in rows) + "  - [0, 0, 0, 1]\n"
    cam1 = "cam1:\n  T_cn_cnm1:\n" + t_lines + "\n".join(cam0.splitlines()[1:]) + "\n"
    path.write_text(cam0 + cam1)
    cal = read_camera_file(path)
    assert cal.right is not None and cal.needs_remap
    rect = Rectifier(cal)
    assert rect.camera.baseline == pytest.approx(np.linalg.norm([0.1101, 0.0004, 0.0008]), rel=1e-4)
    path.write_text(cam0.replace("radtan", "equidistant"))
    cal = read_camera_file(path)
    assert cal.model == "equidistant" and cal.camera.dist == (0.11, -0.22, 0.001, -0.002)
    path.write_text(cam0.replace("  intrinsics: [520.5, 519.75, 321.25, 241.5]\n", ""))
    with pytest.raises(CalibrationError, match=r"detected format: Kalibr camchain, but field 'cam0/intrinsics' is missing"):
        read_camera_file(path)


def test_vslam_yaml_kitti_and_preset(tmp_path):
    y = tmp_path / "camera.yaml"
    y.write_text("fx: 520.5\nfy: 519.75\ncx: 321.25\ncy: 241.5\nwidth: 640\nheight: 480\n"
                 f"dist: {D.tolist()}\n")
    _check(read_camera_file(y), "vslam")
    calib = tmp_path / "calib.txt"
    calib.write_text("P0: 520.5 0 321.25 0 0 519.75 241.5 0 0 0 1 0\n"
                     "P1: 520.5 0 321.25 -57.255 0 519.75 241.5 0 0 0 1 0\n")
    cal = read_camera_file(calib, (640, 480))
    _check(cal, "kitti", dist=(0.0,) * 5)
    assert cal.camera.baseline == pytest.approx(0.11)
    with pytest.raises(CalibrationError, match="KITTI calib.txt, which has no image size"):
        read_camera_file(calib)
    cal = read_camera_file("fr1")
    assert cal.format == "tum-preset" and cal.camera.fx == pytest.approx(517.306408)
    junk = tmp_path / "junk.yaml"
    junk.write_text("foo: 1\n")
    with pytest.raises(CalibrationError, match="unrecognised calibration format"):
        read_camera_file(junk)


def test_folder_with_kitti_calib_and_fisheye_camera(tmp_path):
    seq = tmp_path / "seq"
    seq.mkdir()
    rng = np.random.default_rng(0)
    img = cv2.GaussianBlur(rng.integers(0, 256, (60, 80), dtype=np.uint8), (3, 3), 1)
    for i in range(3):
        cv2.imwrite(str(seq / f"{i:04d}.png"), img)
    (seq / "calib.txt").write_text("P0: 60 0 39.5 0 0 60 29.5 0 0 0 1 0\n")
    ds = open_dataset(seq)
    assert (ds.camera.fx, ds.camera.width, ds.camera.height) == (60, 80, 60)
    assert "KITTI calib.txt" in ds.calibration_source
    fish = tmp_path / "fish.yaml"
    fish.write_text("fx: 40\nfy: 40\ncx: 39.5\ncy: 29.5\nmodel: equidistant\ndist: [0.05, -0.01, 0.002, 0]\n")
    ds = open_dataset(seq, camera=fish)
    assert ds.camera.dist == (0.0,) * 5 and ds.camera.width == 80
    frame = ds[0]
    expected = cv2.remap(img, *ds._rectifier.maps_left, cv2.INTER_LINEAR)
    np.testing.assert_array_equal(frame.image, expected)
    # the remapped pixel of a ray projects where the fisheye model puts it
    X = np.array([[0.3, -0.2, 1.0]])
    uv_pin = ds.camera.project(X)
    uv_fish = cv2.fisheye.projectPoints(X.reshape(-1, 1, 3), np.zeros(3), np.zeros(3),
                                        np.array([[40, 0, 39.5], [0, 40, 29.5], [0, 0, 1.0]]),
                                        np.array([0.05, -0.01, 0.002, 0]))[0].reshape(2)
    back = cv2.fisheye.undistortPoints(uv_fish.reshape(1, 1, 2), np.array([[40, 0, 39.5], [0, 40, 29.5], [0, 0, 1.0]]),
                                       np.array([0.05, -0.01, 0.002, 0]), P=ds.camera.K).reshape(2)
    np.testing.assert_allclose(back, uv_pin[0], atol=1e-3)
    # and the map samples the fisheye image there (to within the map's pixel quantisation)
    mx, my = ds._rectifier.maps_left[0][int(round(uv_pin[0, 1])), int(round(uv_pin[0, 0]))]
    assert abs(mx - uv_fish[0]) < 1.5 and abs(my - uv_fish[1]) < 1.5


@pytest.mark.shared
def test_tum_folder_name_rule_is_overridable(shared_data):
    seq = shared_data / "tum_rgbd_freiburg1_desk_9frames"
    if not seq.is_dir():
        pytest.skip("shared data absent")
    ds = open_dataset(seq)
    assert ds.camera.fx == pytest.approx(517.306408) and "chosen from the folder name" in ds.calibration_source
    ds = open_dataset(seq, camera="fr3")
    assert ds.camera.fx == pytest.approx(535.4)
