"""KITTI odometry reader on the staged sequences 06 (stereo) and 07 (mono)."""
from __future__ import annotations

import numpy as np
import pytest

from vslam.datasets import open_dataset
from vslam.datasets.kitti import KittiDataset, read_kitti_calib
from vslam.errors import CalibrationError, DatasetError

pytestmark = pytest.mark.shared


def test_kitti_06_stereo(shared_data):
    seq = shared_data / "kitti_odometry" / "sequences" / "06"
    ds = open_dataset(seq)
    assert isinstance(ds, KittiDataset) and ds.sensor == "stereo"
    assert len(ds) == 51
    cam = ds.camera
    assert (cam.fx, cam.fy, cam.cx, cam.cy) == (707.0912, 707.0912, 601.8873, 183.1104)
    assert (cam.width, cam.height) == (1226, 370)
    assert cam.baseline == pytest.approx(379.8145 / 707.0912, abs=1e-12)
    assert cam.baseline == pytest.approx(0.53716, abs=2e-5)
    times = np.loadtxt(seq / "times.txt")
    np.testing.assert_allclose(ds.timestamps, times[:51])
    f = ds[10]
    assert f.image.shape == (370, 1226) and f.image_right.shape == (370, 1226) and f.image.dtype == np.uint8
    assert f.depth is None and f.timestamp == times[10]
    poses = np.loadtxt(shared_data / "kitti_odometry" / "poses" / "06.txt")
    np.testing.assert_allclose(f.T_world_cam[:3, :4].ravel(), poses[10])
    gt = ds.ground_truth()
    assert len(gt) == 51
    np.testing.assert_allclose(gt.T_world_cam[:, :3, :4].reshape(-1, 12), poses)


def test_kitti_07_mono_uses_only_rows_with_images(shared_data):
    root = shared_data / "kitti_odometry"
    ds = open_dataset(root / "sequences" / "07")
    assert ds.sensors == ("mono",) and ds.sensor == "mono"
    assert len(ds) == 160
    with pytest.raises(DatasetError, match="image_1"):
        open_dataset(root / "sequences" / "07", sensor="stereo")
    gt = ds.ground_truth()
    poses = np.loadtxt(root / "poses" / "07.txt")
    assert len(poses) == 1101 and len(gt) == 160
    np.testing.assert_allclose(gt.T_world_cam[159, :3, :4].ravel(), poses[159])
    # README: 90.6 m over frames 0-159
    path_len = np.linalg.norm(np.diff(gt.positions, axis=0), axis=1).sum()
    assert path_len == pytest.approx(90.6, abs=0.5)
    frames = list(ds.frames(150, 155))
    assert [f.index for f in frames] == [150, 151, 152, 153, 154]
    assert frames[0].image_right is None


def test_kitti_root_with_two_sequences_asks_for_one(shared_data):
    with pytest.raises(DatasetError, match="pass one sequence"):
        open_dataset(shared_data / "kitti_odometry")


def test_kitti_synthetic_stereo(tmp_path, make_kitti):
    seq = make_kitti(tmp_path / "kitti")
    ds = open_dataset(tmp_path / "kitti")  # a root holding exactly one sequence is accepted
    assert ds.root == seq and ds.camera.baseline == pytest.approx(0.5) and len(ds) == 6
    assert ds[5].T_world_cam[2, 3] == 5.0


def test_kitti_calib_errors(tmp_path, make_kitti):
    seq = make_kitti(tmp_path / "k")
    (seq / "calib.txt").write_text("P0: 100 0 40 0 0 100 20 0 0 0 1\n")
    with pytest.raises(CalibrationError, match=r"calib.txt:1: 'P0' needs 12"):
        open_dataset(seq)
    (seq / "calib.txt").write_text("P1: 100 0 40 -50 0 100 20 0 0 0 1 0\n")
    with pytest.raises(CalibrationError, match="no 'P0:'"):
        read_kitti_calib(seq / "calib.txt")
    (seq / "calib.txt").write_text("P0: 100 0 40 0 0 100 20 0 0 0 1 x\n")
    with pytest.raises(CalibrationError, match="not a number"):
        open_dataset(seq)
    (seq / "calib.txt").unlink()
    with pytest.raises(CalibrationError, match="calib.txt not found"):
        open_dataset(seq)


def test_kitti_times_errors(tmp_path, make_kitti):
    seq = make_kitti(tmp_path / "k")
    np.savetxt(seq / "times.txt", [0.0, 0.1, 0.2])
    with pytest.raises(DatasetError, match="has 3 timestamps but image_0/ holds frame 5"):
        open_dataset(seq)
    np.savetxt(seq / "times.txt", [0.0, 0.1, 0.3, 0.2, 0.4, 0.5])
    with pytest.raises(DatasetError, match="not sorted"):
        open_dataset(seq)
    (seq / "times.txt").unlink()
    with pytest.raises(DatasetError, match="times.txt not found"):
        open_dataset(seq)
