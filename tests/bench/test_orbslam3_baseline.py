"""The optional ORB-SLAM3 baseline plumbing: clear errors without pyorbslam3 / vocabulary, settings."""
from __future__ import annotations

import importlib.util

import numpy as np

import pytest

from vslam.bench import orbslam3_baseline as orb
from vslam.errors import VslamError
from vslam.geometry.camera import PinholeCamera


def test_needs_a_vocabulary(tmp_path):
    with pytest.raises(VslamError, match="--vocabulary FILE"):
        orb.check_available(None)
    with pytest.raises(VslamError, match="vocabulary not found"):
        orb.check_available(tmp_path / "ORBvoc.txt")


@pytest.mark.skipif(importlib.util.find_spec("pyorbslam3") is not None, reason="pyorbslam3 is installed")
def test_missing_wheel_is_a_clear_error(tmp_path):
    voc = tmp_path / "ORBvoc.txt"
    voc.write_text("10 4 0 0\n")
    with pytest.raises(VslamError, match=r"pip install pyorbslam3"):
        orb.make_runner(voc)


def test_settings_use_the_old_keys_and_viewer_block():
    cam = PinholeCamera(fx=707.0912, fy=707.0912, cx=601.8873, cy=183.1104, width=1226, height=370, baseline=0.53716)
    text = orb.settings_yaml(cam, "stereo", 10.0)
    assert text.startswith("%YAML:1.0")
    assert "Camera.fx: 707.0912" in text and "Camera.width: 1226" in text and "Camera.fps: 10" in text
    assert f"Camera.bf: {707.0912 * 0.53716}" in text
    assert "Viewer.ViewpointF" in text and "Rectified" not in text


def test_runner_plumbing_with_a_stand_in_wheel(tmp_path, monkeypatch, shared_data):
    """run_orbslam3 with a fake ``pyorbslam3`` whose Slam returns the ground-truth pose: the run folder
    holds that trajectory and an ATE of ~0, lost frames are dropped, the settings file is written."""
    import json
    import types

    from vslam.datasets import open_dataset
    from vslam.eval.trajectory import read_trajectory

    seq = shared_data / "tum_rgbd_freiburg1_desk_9frames"
    ds = open_dataset(seq, sensor="rgbd")
    gt_by_time = dict(zip(ds.ground_truth().timestamps.tolist(), ds.ground_truth().T_world_cam))
    created = []

    class FakeSlam:
        def __init__(self, vocab, settings, sensor, use_viewer=False):
            created.append((vocab, settings, sensor, use_viewer))
            self.n = 0

        def track_rgbd(self, image, depth, t):
            assert depth.dtype == np.float32 and image.shape[:2] == depth.shape
            self.n += 1
            valid = self.n != 3  # the third frame is "lost"
            return types.SimpleNamespace(pose_valid=valid, pose_wc=gt_by_time[t] if valid else None)

        def shutdown(self):
            created.append("shutdown")

    fake = types.SimpleNamespace(Slam=FakeSlam, Sensor=types.SimpleNamespace(MONOCULAR=0, STEREO=1, RGBD=2))
    monkeypatch.setattr(orb, "_import_pyorbslam3", lambda: fake)
    voc = tmp_path / "voc.txt"
    voc.write_text("x")
    runner = orb.make_runner(voc)
    out = tmp_path / "run"
    stats = runner(str(seq), out, sensor="rgbd", pace=False)
    assert created[0][2] == 2 and created[0][3] is False and created[-1] == "shutdown"
    assert stats["frames"] == 9 and stats["tracked"] == 8 and stats["lost"] == 1
    assert stats["ate_rmse"] < 1e-4 and stats["system"] == "orbslam3"
    assert len(read_trajectory(out / "trajectory.txt")) == 8
    assert json.loads((out / "stats.json").read_text())["tracked"] == 8
    assert "DepthMapFactor: 1.0" in (out / "orbslam3_settings.yaml").read_text()
