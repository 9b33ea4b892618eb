"""``vslam run --camera`` / ``--trajectory-format``, and an ORB-SLAM settings file passed as --config."""
from __future__ import annotations

import json

import numpy as np
import pytest

from vslam.cli import main
from vslam.trajectory import read_kitti, read_tum

ORB3 = ('%YAML:1.0\nCamera.type: "PinHole"\nCamera1.fx: 517.306408\nCamera1.fy: 516.469215\n'
        "Camera1.cx: 318.643040\nCamera1.cy: 255.313989\nCamera1.k1: 0.262383\nCamera1.k2: -0.953104\n"
        "Camera1.p1: -0.005358\nCamera1.p2: 0.002628\nCamera1.k3: 1.163314\nCamera.width: 640\n"
        "Camera.height: 480\nRGBD.DepthMapFactor: 5000.0\n")


@pytest.fixture
def fr1(shared_data):
    return shared_data / "tum_rgbd_freiburg1_desk_9frames"


def test_orbslam_settings_as_config_points_to_camera(fr1, tmp_path, capsys):
    orb = tmp_path / "TUM1.yaml"
    orb.write_text(ORB3)
    rc = main(["run", str(fr1), "-o", str(tmp_path / "out"), "--config", str(orb)])
    err = capsys.readouterr().err
    assert rc == 2 and "ORB-SLAM3 v1.0 settings" in err and f"pass it as --camera {orb}" in err
    rc = main(["run", str(fr1), "-o", str(tmp_path / "out"), "--camera", str(tmp_path / "nope.yaml")])
    assert rc == 2 and "nope.yaml: camera file not found" in capsys.readouterr().err


def test_run_with_orbslam3_camera_equals_preset_and_exports_kitti(fr1, tmp_path, capsys):
    """fr1 intrinsics from an ORB-SLAM3 file give the same poses as the folder-name preset;
    a wrong preset (--camera fr3) changes them; --trajectory-format kitti writes the same poses."""
    orb = tmp_path / "orb3.yaml"
    orb.write_text(ORB3)
    assert main(["run", str(fr1), "-o", str(tmp_path / "a"), "--no-progress"]) == 0
    assert main(["run", str(fr1), "-o", str(tmp_path / "b"), "--no-progress", "--camera", str(orb),
                 "--trajectory-format", "kitti"]) == 0
    assert main(["run", str(fr1), "-o", str(tmp_path / "c"), "--no-progress", "--camera", "fr3"]) == 0
    out = capsys.readouterr().out
    assert "chosen from the folder name 'tum_rgbd_freiburg1_desk_9frames'" in out
    assert "ORB-SLAM3 v1.0 settings" in out
    a, b, c = (read_tum(tmp_path / x / "trajectory.txt") for x in "abc")
    np.testing.assert_allclose(b.T_world_cam, a.T_world_cam, atol=1e-9)
    assert np.abs(c.T_world_cam - a.T_world_cam).max() > 1e-4
    k = read_kitti(tmp_path / "b" / "trajectory_kitti.txt", tmp_path / "b" / "trajectory_kitti_times.txt")
    np.testing.assert_allclose(k.timestamps, b.timestamps, atol=1e-6)
    np.testing.assert_allclose(k.T_world_cam, b.T_world_cam, atol=1e-8)
    sa, sb = (json.loads((tmp_path / x / "stats.json").read_text()) for x in "ab")
    assert sa["ate_rmse"] == pytest.approx(sb["ate_rmse"], abs=1e-12)
    assert sa["ate_rmse"] == pytest.approx(0.0028, abs=0.0003)
