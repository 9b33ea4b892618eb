"""Rectified stereo matching: exact synthetic disparity, and the real KITTI 06 frame-0 pair
cross-checked against OpenCV's semi-global matcher."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from vslam.errors import CalibrationError, ConfigError
from vslam.features import FeatureConfig, StereoConfig, create_detector, match_stereo, stereo_depth
from vslam.features.stereo import _candidate_pairs, match_stereo_descriptors, refine_disparity_row

FX, BASELINE = 707.0912, 0.53716


@pytest.mark.parametrize("disparity", [12.3, 20.5])
def test_synthetic_disparity_subpixel(gravel, shift_image, disparity):
    right = shift_image(gravel, -disparity, 0.0)  # a fronto-parallel plane: u_r = u_l - d
    det = create_detector(FeatureConfig(n_features=1000))
    fl, fr = det.detect(gravel), det.detect(right)
    li, ur = match_stereo(fl, fr, StereoConfig(max_disparity=40), gravel, right)
    u_l = fl.uv[li, 0]
    inside = (u_l > 40) & (u_l < gravel.shape[1] - 40)  # away from the periodic wrap
    err = np.abs((u_l - ur) - disparity)[inside]
    assert inside.sum() > 400
    assert np.median(err) < 0.05 and (err < 0.2).mean() > 0.95
    # ORB-SLAM's parabola on SAD alone is coarser (a known bias)
    li_p, ur_p = match_stereo(fl, fr, StereoConfig(max_disparity=40, subpixel="parabola"), gravel, right)
    err_p = np.abs((fl.uv[li_p, 0] - ur_p) - disparity)
    assert np.median(err_p) > np.median(err)


@pytest.mark.parametrize("base", [12, 47])
def test_refine_disparity_row_unbiased(gravel, shift_image, base):
    """Row-constrained LK recovers exactly known disparities from starts up to 2.5 px off. Linear
    interpolation leaves a small error that depends on the sub-pixel part (pixel locking, odd
    about integers and half-integers); over the sub-pixel parts it averages out: no bias in depth
    (mean error < 0.1 % of the disparity)."""
    rng = np.random.default_rng(4)
    uv = np.column_stack([rng.uniform(80, 430, 300), rng.uniform(20, 490, 300)])
    errs = []
    for frac in np.arange(0.05, 1.0, 0.1):
        disparity = base + frac
        right = shift_image(gravel, -disparity, 0.0)
        d0 = disparity + rng.uniform(-2.5, 2.5, len(uv))
        d, ok = refine_disparity_row(gravel, right, uv, d0)
        assert ok.mean() > 0.95
        err = d[ok] - disparity
        assert np.median(np.abs(err)) < 0.04
        errs.append(np.median(err))
    assert np.abs(np.mean(errs)) < 1e-3 * base
    # NaN starts are skipped; windows leaving the image are refused, not clipped
    d, ok = refine_disparity_row(gravel, right, np.array([[200.0, 100.0], [3.0, 100.0], [20.0, 100.0]]),
                                 np.array([np.nan, 10.0, 30.0]))
    assert not ok.any() and np.isnan(d[0])


def test_candidate_pairs_equal_bruteforce():
    rng = np.random.default_rng(0)
    v_l = rng.uniform(0, 100, 200)
    v_r = rng.uniform(0, 100, 300)
    li, rj = _candidate_pairs(v_l, v_r, 2.0)
    ref = np.argwhere(np.abs(v_l[:, None] - v_r[None, :]) <= 2.0)
    got = np.stack([li, rj], 1)
    assert {tuple(p) for p in got.tolist()} == {tuple(p) for p in ref.tolist()} and len(got) == len(ref)


@pytest.fixture(scope="module")
def kitti_pair(shared_data):
    seq = shared_data / "kitti_odometry/sequences/06"
    left = cv2.imread(str(seq / "image_0/000000.png"), cv2.IMREAD_GRAYSCALE)
    right = cv2.imread(str(seq / "image_1/000000.png"), cv2.IMREAD_GRAYSCALE)
    det = create_detector(FeatureConfig(n_features=2000))
    return left, right, det.detect(left), det.detect(right)


@pytest.mark.shared
def test_kitti_stereo_consistent(kitti_pair):
    left, right, fl, fr = kitti_pair
    li, ur = match_stereo(fl, fr, StereoConfig(), left, right, fx=FX, baseline=BASELINE)
    li0, ur0 = match_stereo(fl, fr, StereoConfig(refine=False), fx=FX, baseline=BASELINE)
    assert len(li) > 700 and len(li0) >= len(li)
    # refinement is a sub-pixel correction of the descriptor match
    common, a, b = np.intersect1d(li, li0, return_indices=True)
    change = np.abs(ur[a] - ur0[b])
    assert np.median(change) < 1.0 and np.percentile(change, 90) < 2.5
    depth = stereo_depth(fl.uv[li, 0], ur, FX, BASELINE)
    assert (depth > 0).all() and np.isfinite(depth).all() and (depth >= StereoConfig().min_depth).all()
    # an independent dense estimate (OpenCV SGBM) agrees on most keypoints
    sgbm = cv2.StereoSGBM_create(0, 128, 5, P1=8 * 25, P2=32 * 25, uniquenessRatio=10,
                                 mode=cv2.STEREO_SGBM_MODE_HH)
    dense = sgbm.compute(left, right).astype(np.float32) / 16.0
    u, v = fl.uv[li, 0], fl.uv[li, 1]
    d_sgbm = dense[np.round(v).astype(int), np.round(u).astype(int)]
    valid = d_sgbm > 0
    err = np.abs((u - ur) - d_sgbm)[valid]
    assert valid.sum() > 500 and np.median(err) < 0.35 and (err < 1.0).mean() > 0.85


@pytest.mark.shared
def test_kitti_stereo_row_constraint(kitti_pair):
    """Rectified: matched right keypoints lie on the left keypoint's row (within the band)."""
    left, right, fl, fr = kitti_pair
    li, j = match_stereo_descriptors(fl, fr, StereoConfig(), max_disparity=FX * BASELINE / 0.5)
    row_err = np.abs(fr.uv[j, 1] - fl.uv[li, 1])
    assert len(li) > 700
    assert np.median(row_err) < 1.0 and (row_err <= 2.0 * 1.2 ** fr.octave[j] + 1e-6).all()


def test_config_and_calibration_errors(gravel):
    with pytest.raises(ConfigError):
        StereoConfig(subpixel="cubic")
    det = create_detector(FeatureConfig(n_features=100))
    f = det.detect(gravel)
    with pytest.raises(CalibrationError, match="baseline"):
        match_stereo(f, f, fx=FX, baseline=-0.1)
    li, ur = match_stereo(f.subset(np.zeros(0, int)), f)
    assert len(li) == len(ur) == 0


def test_stereo_depth():
    z = stereo_depth(np.array([110.0, 50.0]), np.array([100.0, 50.0]), FX, BASELINE)
    assert z[0] == pytest.approx(FX * BASELINE / 10.0) and np.isinf(z[1])
