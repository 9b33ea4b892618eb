"""KLT tracking on exactly shifted images, the forward-backward check, and re-detection."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from vslam.errors import ConfigError, VslamError
from vslam.features import KLTConfig, detect_new_points, occupancy_mask, track_klt


def corners(img: np.ndarray, n: int = 400, margin: int = 40) -> np.ndarray:
    p = cv2.goodFeaturesToTrack(img, n, 0.01, 10).reshape(-1, 2)
    h, w = img.shape
    keep = (p[:, 0] > margin) & (p[:, 1] > margin) & (p[:, 0] < w - margin) & (p[:, 1] < h - margin)
    return p[keep].astype(np.float32)


@pytest.mark.parametrize("du,dv", [(1.3, -0.7), (6.4, 3.25)])
def test_tracks_subpixel_shift(gravel, shift_image, du, dv):
    curr = shift_image(gravel, du, dv)
    p0 = corners(gravel)
    uv, ok = track_klt(gravel, curr, p0, KLTConfig())
    err = np.linalg.norm(uv - (p0 + [du, dv]), axis=1)
    assert len(p0) > 200 and ok.mean() >= 0.98
    assert np.median(err[ok]) < 0.05 and err[ok].max() < 0.1


def test_initial_flow_allows_large_motion(gravel, shift_image):
    """A 30 px shift is out of reach of a single-level LK; a prediction within 2 px fixes it."""
    curr = shift_image(gravel, 30.0, 0.0)
    p0 = corners(gravel)
    cfg = KLTConfig(max_level=0)
    uv_plain, ok_plain = track_klt(gravel, curr, p0, cfg)
    uv, ok = track_klt(gravel, curr, p0, cfg, init_uv=p0 + [28.5, 1.0])
    err = np.linalg.norm(uv - (p0 + [30.0, 0.0]), axis=1)
    err_plain = np.linalg.norm(uv_plain - (p0 + [30.0, 0.0]), axis=1)
    assert (ok_plain & (err_plain < 0.5)).mean() < 0.1
    assert ok.mean() > 0.95 and np.percentile(err[ok], 95) < 0.1


def test_forward_backward_rejects_occluded_points(brick, shift_image):
    curr = shift_image(brick, 2.0, 1.0)
    rng = np.random.default_rng(0)
    curr[:, 256:] = rng.integers(0, 256, (512, 256), dtype=np.uint8)  # right half replaced by noise
    p0 = corners(brick, 600)
    uv, ok = track_klt(brick, curr, p0, KLTConfig())
    occluded = p0[:, 0] > 256 + 15  # the LK window does not reach the clean half
    clean = p0[:, 0] < 256 - 15
    assert ok[clean].mean() > 0.95
    assert ok[occluded].mean() < 0.05
    # without the check, far more garbage survives
    _, ok_nofb = track_klt(brick, curr, p0, KLTConfig(fb_threshold=0))
    assert ok_nofb[occluded].mean() > ok[occluded].mean() + 0.2


def test_border_check(brick):
    p0 = np.array([[1.0, 200.0], [256.0, 256.0]], np.float32)
    uv, ok = track_klt(brick, brick, p0, KLTConfig(border=5))
    assert not ok[0] and ok[1]
    np.testing.assert_allclose(uv[1], p0[1], atol=0.01)


def test_empty_and_bad_inputs(brick):
    uv, ok = track_klt(brick, brick, np.zeros((0, 2)))
    assert uv.shape == (0, 2) and ok.shape == (0,)
    with pytest.raises(VslamError, match="init_uv"):
        track_klt(brick, brick, np.zeros((3, 2)), init_uv=np.zeros((2, 2)))
    with pytest.raises(VslamError, match="uint8"):
        track_klt(brick.astype(np.float32), brick, np.zeros((3, 2)))
    with pytest.raises(ConfigError):
        KLTConfig(win_size=20)


def test_detect_new_points_fills_empty_cells(astronaut):
    gu, gv = np.meshgrid(np.arange(0, 250, 10.0), np.arange(0, 512, 10.0))
    existing = np.c_[gu.ravel(), gv.ravel()]  # tracks cover the left half densely
    new = detect_new_points(astronaut, existing, max_total=len(existing) + 150, min_distance=12, cell_size=40)
    assert 100 <= len(new) <= 150
    # far from every existing point, so all in the empty right half, spread over its cells
    d = np.linalg.norm(new[:, None] - existing[None], axis=2).min(1)
    assert d.min() >= 11.5 and (new[:, 0] > 250).all()
    cells = {(int(u // 40), int(v // 40)) for u, v in new}
    assert len(cells) >= 0.6 * (240 // 40) * (512 - 40) // 40
    # nothing new when the budget is used up
    assert len(detect_new_points(astronaut, existing, max_total=len(existing))) == 0


def test_detect_new_points_with_descriptors(astronaut):
    feats = detect_new_points(astronaut, np.zeros((0, 2)), max_total=200, describe=True, method="fast")
    assert 150 <= len(feats) <= 200 and feats.descriptors.shape == (len(feats), 32) and feats.binary


def test_occupancy_mask():
    m = occupancy_mask((50, 60), np.array([[10.0, 20.0]]), 5)
    assert m[20, 10] == 0 and m[20, 15] == 0 and m[20, 16] == 255 and m.dtype == np.uint8



@pytest.mark.parametrize("win,levels,iters", [(11, 4, 5), (11, 0, 1), (21, 3, 30)])
def test_lk_without_error_output_same_as_opencv(gravel, win, levels, iters):
    """``_pyr_lk`` asks OpenCV for no patch difference (``OPTFLOW_LK_GET_MIN_EIGENVALS``, cheaper)
    and repeats the test that pass made: positions and status equal OpenCV's default call. The
    starts lie just left of the image, so some points end a window outside it after the last step
    and only that test refuses them."""
    from vslam.features.klt import _pyr_lk

    rng = np.random.default_rng(0)
    p0 = np.column_stack([rng.uniform(20, 490, 2000), rng.uniform(20, 490, 2000)]).astype(np.float32).reshape(-1, 1, 2)
    init = p0.copy()
    init[:, 0, 0] = rng.uniform(-10.0, 0.0, len(p0))
    cfg = KLTConfig(win_size=win, max_level=levels, max_iter=iters, eps=0.01)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, iters, 0.01)
    kw = dict(winSize=(win, win), maxLevel=levels, criteria=crit, minEigThreshold=cfg.min_eig_threshold)
    p1_ref, st_ref, _ = cv2.calcOpticalFlowPyrLK(gravel, gravel, p0, init.copy(), flags=cv2.OPTFLOW_USE_INITIAL_FLOW, **kw)
    _, st_raw, _ = cv2.calcOpticalFlowPyrLK(gravel, gravel, p0, init.copy(),
                                            flags=cv2.OPTFLOW_USE_INITIAL_FLOW | cv2.OPTFLOW_LK_GET_MIN_EIGENVALS, **kw)
    p1, ok = _pyr_lk(gravel, gravel, p0, init.copy(), cfg, crit, cv2.OPTFLOW_USE_INITIAL_FLOW)
    np.testing.assert_array_equal(p1, p1_ref)
    np.testing.assert_array_equal(ok, st_ref.reshape(-1).astype(bool))
    assert (st_raw.reshape(-1).astype(bool) & ~ok).sum() >= 2  # the repeated test was needed
    assert 0.4 < ok.mean() < 0.7
