"""The camera YAML: the small format and ORB-SLAM style files."""
from __future__ import annotations

import pytest

from vslam.datasets.camera_yaml import read_camera_yaml
from vslam.errors import CalibrationError


def test_camera_yaml_small_and_orbslam(tmp_path):
    p = tmp_path / "camera.yaml"
    p.write_text("fx: 500\nfy: 501\ncx: 320\ncy: 240\nwidth: 640\nheight: 480\ndist: [0.1, -0.2, 0.001, 0.002]\n"
                 "baseline: 0.12\nfps: 20\n")
    cam, extras = read_camera_yaml(p)
    assert (cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height) == (500, 501, 320, 240, 640, 480)
    assert cam.dist == (0.1, -0.2, 0.001, 0.002, 0.0) and cam.baseline == 0.12
    assert extras == {"fps": 20.0}
    p.write_text("fx: 500\nfy: 501\ncx: 320\ncy: 240\n")
    with pytest.raises(CalibrationError, match="lacks 'width'"):
        read_camera_yaml(p)
    cam, _ = read_camera_yaml(p, image_size=(752, 480))
    assert (cam.width, cam.height) == (752, 480)
    orb = tmp_path / "TUM3.yaml"
    orb.write_text("%YAML:1.0\nCamera.fx: 535.4\nCamera.fy: 539.2\nCamera.cx: 320.1\nCamera.cy: 247.6\n"
                   "Camera.k1: 0.0\nCamera.k2: 0.0\nCamera.p1: 0.0\nCamera.p2: 0.0\nCamera.fps: 30.0\n"
                   "Camera.bf: 40.0\nDepthMapFactor: 5000.0\n")
    cam, extras = read_camera_yaml(orb, image_size=(640, 480))
    assert (cam.fx, cam.fy, cam.cx, cam.cy) == (535.4, 539.2, 320.1, 247.6)
    assert cam.baseline == pytest.approx(40 / 535.4) and extras == {"depth_scale": 5000.0, "fps": 30.0}
