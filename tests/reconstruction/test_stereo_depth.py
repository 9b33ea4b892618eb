"""SGBM stereo depth against the synthetic renderer's exact depth, and on real KITTI 06."""
from __future__ import annotations

import numpy as np
import pytest

from vslam.errors import CalibrationError, VslamError
from vslam.reconstruction.stereo_depth import StereoDepthConfig, default_max_depth, depth_from_stereo


def test_sgbm_depth_matches_exact_depth(synthetic_frames):
    errs, valid = [], []
    for frame in synthetic_frames[:4]:
        depth = depth_from_stereo(frame.gray, frame.image_right, frame.camera)
        in_range = (frame.depth > 0) & (frame.depth < default_max_depth(frame.camera))
        ok = (depth > 0) & (frame.depth > 0)
        valid.append((depth > 0)[in_range].mean())  # SGBM found depth where the truth is in range
        errs.append(np.abs(depth[ok] - frame.depth[ok]) / frame.depth[ok])
    rel = np.concatenate(errs)
    # the 320x240 rig has fx B = 26.25 px m: at 3 m a quarter-pixel disparity error is ~3 % of depth
    assert np.median(rel) < 0.02, np.median(rel)
    assert np.mean(rel < 0.05) > 0.8
    assert min(valid) > 0.6, valid


def test_max_depth_and_border_filters(synthetic_frames):
    frame = synthetic_frames[0]
    depth = depth_from_stereo(frame.gray, frame.image_right, frame.camera, max_depth=2.0)
    assert depth.dtype == np.float32 and depth.shape == frame.depth.shape
    assert depth.max() <= 2.0 and (depth > 0).any()
    assert not depth[:4].any() and not depth[:, -4:].any()
    # default range: where the disparity falls to 8 px
    assert default_max_depth(frame.camera) == pytest.approx(262.5 * 0.1 / 8)


def test_bad_input_raises(synthetic_frames):
    frame = synthetic_frames[0]
    mono = type(frame.camera)(262.5, 262.5, 159.5, 119.5, 320, 240)
    with pytest.raises(CalibrationError, match="baseline"):
        depth_from_stereo(frame.gray, frame.image_right, mono)
    with pytest.raises(VslamError, match="differ in size"):
        depth_from_stereo(frame.gray, frame.gray[:100], frame.camera)
    with pytest.raises(VslamError, match="multiple of 16"):
        StereoDepthConfig(num_disparities=100)


def test_kitti_sgbm_depth_is_plausible(shared_data):
    from vslam.datasets import open_dataset

    ds = open_dataset(shared_data / "kitti_odometry" / "sequences" / "06", kind="kitti", sensor="stereo")
    frame = ds[0]
    depth = depth_from_stereo(frame.gray, frame.image_right, frame.camera)
    valid = depth > 0
    assert valid.mean() > 0.4
    assert 5.0 < np.median(depth[valid]) < 40.0
    # the road right in front of the car: the camera sits 1.65 m above it (KITTI setup), so the
    # bottom-centre rows see the road at z = fy * 1.65 / (v - cy)
    v = np.arange(330, 360)
    rows = depth[330:360, 550:650]
    expected = frame.camera.fy * 1.65 / (v - frame.camera.cy)
    got = np.array([np.median(r[r > 0]) for r in rows])
    np.testing.assert_allclose(got, expected, rtol=0.1)
