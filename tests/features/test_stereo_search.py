"""Row-constrained pyramidal Lucas-Kanade (:func:`vslam.features.stereo_search.match_rows`): exactly
known sub-pixel disparities (small, and large ones only the pyramid reaches), no match without row
texture, wrong minima rejected by correlation, and on KITTI 06 the same disparities as the 2-D
tracker's path."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from vslam.features.stereo_search import match_rows, row_pyramid, usable_levels

def _texture(h: int, w: int, seed: int) -> np.ndarray:
    """Gaussian noise smoothed at 1, 2, 4, 8 and 16 px, summed: texture at every pyramid level."""
    rng = np.random.default_rng(seed)
    acc = np.zeros((h, w))
    for s in (1, 2, 4, 8, 16):
        n = cv2.GaussianBlur(rng.standard_normal((h, w)), (0, 0), s)
        acc += n / n.std()
    return np.clip(128 + 40 * acc / acc.std(), 0, 255).astype(np.uint8)


@pytest.fixture(scope="module")
def multiscale() -> np.ndarray:
    return _texture(480, 752, 1)


@pytest.mark.parametrize("disparity", [3.3, 12.72, 35.45])
def test_match_rows_recovers_known_disparity(multiscale, shift_image, disparity):
    """From zero, 300 sub-pixel points of a pair shifted by ``disparity``: recovered to < 0.05 px
    for 90 % (median < 0.03 px; linear interpolation's pixel locking is the rest), 97 % ok. A
    single level (no pyramid) finds 12.7 px and 35.5 px for almost none."""
    right = shift_image(multiscale, -disparity, 0.0)
    rng = np.random.default_rng(7)
    uv = np.column_stack([rng.uniform(110, 740, 300), rng.uniform(15, 465, 300)])
    d, ok = match_rows(multiscale, right, uv)
    assert ok.mean() > 0.97
    err = np.abs(d - disparity)[ok]
    assert np.percentile(err, 90) < 0.05 and np.median(err) < 0.03
    d1, ok1 = match_rows(multiscale, right, uv, levels=0)
    found = (ok1 & (np.abs(d1 - disparity) < 0.1)).mean()
    assert found > 0.9 if disparity < 4 else found < 0.05


def test_match_rows_zncc_rejects_wrong_minima(multiscale, shift_image):
    """12.72 px searched from zero on one level ends in wrong minima for most points; the
    normalized cross-correlation test rejects most of them, and keeps the right matches of the
    pyramid (their correlation is ~1)."""
    right = shift_image(multiscale, -12.72, 0.0)
    rng = np.random.default_rng(7)
    uv = np.column_stack([rng.uniform(110, 740, 300), rng.uniform(15, 465, 300)])
    d, ok, z = match_rows(multiscale, right, uv, levels=0, return_zncc=True)
    wrong = ok & (np.abs(d - 12.72) > 0.5)
    assert wrong.sum() > 100
    _, ok5 = match_rows(multiscale, right, uv, levels=0, min_zncc=0.5)
    assert (ok5 & wrong).sum() < 0.3 * wrong.sum()
    np.testing.assert_array_equal(ok5, ok & (z >= 0.5))
    d4, ok4, z4 = match_rows(multiscale, right, uv, min_zncc=0.5, return_zncc=True)
    assert ok4.mean() > 0.97 and np.median(z4[ok4]) > 0.99


def test_match_rows_initial_disparity(gravel, shift_image):
    """A given initial disparity is where the search starts: 61.91 px from 60 on a single level
    (from 0 it is out of reach, ``test_match_rows_recovers_known_disparity``)."""
    right = shift_image(gravel, -61.91, 0.0)
    rng = np.random.default_rng(3)
    uv = np.column_stack([rng.uniform(100, 490, 200), rng.uniform(20, 490, 200)])
    d, ok = match_rows(gravel, right, uv, np.full(len(uv), 60.0), levels=0)
    assert ok.mean() > 0.95
    assert np.percentile(np.abs(d[ok] - 61.91), 95) < 0.05


def test_match_rows_no_row_texture_not_ok(gravel, shift_image):
    """Windows on a flat patch, on a vertical-only texture (rows constant along x) or on a linear
    ramp along x (constant gradient: a brightness offset explains it as well as a shift) are not
    ok; textured ones beside them are."""
    img = gravel.copy()
    img[:, 256:] = 128  # flat
    img[:200, 256:384] = (np.arange(200)[:, None] % 7 * 30).astype(np.uint8)  # texture along y only
    img[300:, 256:384] = np.clip(40 + 1.5 * np.arange(128), 0, 255).astype(np.uint8)[None, :]  # ramp along x
    right = shift_image(img, -7.4, 0.0)
    right[:, 256:] = np.roll(img, -7, axis=1)[:, 256:]  # integer shift there (no ringing of the FFT shift)
    rng = np.random.default_rng(5)
    tex = np.column_stack([rng.uniform(40, 200, 100), rng.uniform(40, 470, 100)])
    flat = np.column_stack([rng.uniform(400, 490, 100), rng.uniform(20, 490, 100)])
    vert = np.column_stack([rng.uniform(280, 360, 100), rng.uniform(20, 180, 100)])
    ramp = np.column_stack([rng.uniform(280, 360, 100), rng.uniform(320, 490, 100)])
    pts = np.concatenate([tex, flat, vert, ramp])
    _, ok = match_rows(img, right, pts, np.full(len(pts), 7.0), levels=0)
    assert ok[:100].mean() > 0.95
    assert not ok[100:].any()


def test_row_pyramid_layout():
    """Levels are cv2.pyrDown images, each padded (reflect-101) and packed one after another."""
    img = (np.arange(37 * 53).reshape(37, 53) % 251).astype(np.uint8)
    flat, offs, ws, hs = row_pyramid(img, 2, 4)
    lev1 = cv2.pyrDown(img)
    assert list(ws) == [53, lev1.shape[1], cv2.pyrDown(lev1).shape[1]] and list(hs) == [37, 19, 10]
    got = flat[offs[1]:offs[2]].reshape(hs[1] + 8, ws[1] + 8)
    np.testing.assert_array_equal(got[4:-4, 4:-4], lev1)
    np.testing.assert_array_equal(got[4:-4, 3], lev1[:, 1])  # reflect-101
    assert usable_levels((376, 1241), 4, 11) == 4 and usable_levels((300, 400), 4, 11) == 3


@pytest.mark.shared
def test_match_rows_kitti_agrees_with_lk2d_path(shared_data):
    """KITTI 06, 2000 ORB keypoints: after the row refinement the row path gives the 2-D tracker
    path's disparities (within 0.1 px) for 90 % of the points both match; it matches at least as
    many points, 80 % of the 2-D path's among them (that path drops those whose rows drift by
    1.5 px, this one those whose windows correlate less than 0.5)."""
    from vslam.features import FeatureConfig, create_detector
    from vslam.frontend.observation import stereo_by_flow
    from vslam.geometry.camera import PinholeCamera

    seq = shared_data / "kitti_odometry/sequences/06"
    cam = PinholeCamera(707.0912, 707.0912, 601.8873, 183.1104, 1226, 370, baseline=379.8145 / 707.0912)
    det = create_detector(FeatureConfig(n_features=2000))
    for i in (0, 25):
        left = cv2.imread(str(seq / f"image_0/{i:06d}.png"), cv2.IMREAD_GRAYSCALE)
        right = cv2.imread(str(seq / f"image_1/{i:06d}.png"), cv2.IMREAD_GRAYSCALE)
        uv = np.asarray(det.detect(left).uv, float)
        _, ur_2d = stereo_by_flow(left, right, uv, cam, flow="lk2d")
        _, ur_row = stereo_by_flow(left, right, uv, cam, flow="row")
        m2, mr = np.isfinite(ur_2d), np.isfinite(ur_row)
        assert mr.sum() >= m2.sum() > 900
        both = m2 & mr
        assert both.sum() > 0.8 * m2.sum()
        assert (np.abs(ur_2d - ur_row)[both] < 0.1).mean() > 0.9
        # the row stage alone, before the refinement: within 1 px of the final value
        d, ok = match_rows(left, right, uv)
        assert (np.abs(d - (uv[:, 0] - ur_row))[ok & mr] < 1.0).mean() > 0.95
