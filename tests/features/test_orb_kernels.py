"""The compiled detector bookkeeping (vslam.features.orb_kernels) and the cropped FAST against the
NumPy / whole-image code they replaced (kept here as references): results must be identical."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from tests.features._orb_reference import opencv_orb
from vslam.features.config import FeatureConfig
from vslam.features.detect import OrbGridDetector
from vslam.features.orb_describe import Orientation, responses
from vslam.features.pyramid import build_pyramid, grid_select


def _orientation_ref(o: Orientation, img, x, y):
    """The integral-image version (row sums for m01, column sums for m10)."""
    ii = cv2.integral(img, sdepth=cv2.CV_32S)
    f = ii.reshape(-1)
    w1 = ii.shape[1]
    d = np.arange(-o.radius, o.radius + 1).astype(np.int64)
    u = o.umax
    k = (np.asarray(y, np.int64) * w1 + np.asarray(x, np.int64))[:, None]
    r0, r1 = d * w1, (d + 1) * w1
    rows = f[k + (r1 + u + 1)] - f[k + (r1 - u)] - f[k + (r0 + u + 1)] + f[k + (r0 - u)]
    t, btm = -u * w1, (u + 1) * w1
    cols = f[k + (btm + d + 1)] - f[k + (btm + d)] - f[k + (t + d + 1)] + f[k + (t + d)]
    m01 = rows.astype(np.float64) @ d.astype(np.float64)
    m10 = cols.astype(np.float64) @ d.astype(np.float64)
    return np.mod(np.degrees(np.arctan2(m01, m10)), 360.0).astype(np.float32)


def _grid_select_ref(uv, score, cell_size, n_keep):
    """The two-sort NumPy version."""
    n = len(uv)
    score = np.asarray(score)
    idx = np.arange(n, dtype=np.int64)
    if n and np.all(score == np.round(score)) and score.min() >= 0 and score.max() < 2**16:
        srank = (int(score.max()) - score).astype(np.int64) * n + idx
    else:
        srank = np.empty(n, np.int64)
        srank[np.argsort(-score, kind="stable")] = idx
    if n <= n_keep:
        return np.argsort(srank)
    span = int(srank.max()) + 1
    cx = (uv[:, 0] // cell_size).astype(np.int64)
    cy = (uv[:, 1] // cell_size).astype(np.int64)
    cell = cy * (int(cx.max()) + 1) + cx
    order = np.argsort(cell * span + srank)
    cs = cell[order]
    start = np.r_[True, cs[1:] != cs[:-1]]
    first = np.maximum.accumulate(np.where(start, idx, 0))
    rank = np.empty(n, np.int64)
    rank[order] = idx - first
    key = rank * span + srank
    part = np.argpartition(key, n_keep - 1)[:n_keep] if n_keep > 0 else np.zeros(0, np.int64)
    return part[np.argsort(key[part])]


def _fast_ref(det: OrbGridDetector, img, mask):
    """FAST on the whole image, then the descriptor-border filter."""
    kps = det.fast.detect(img, mask)
    pts = cv2.KeyPoint_convert(kps).reshape(-1, 2)
    x, y, s = pts[:, 0].astype(np.int64), pts[:, 1].astype(np.int64), responses(kps)
    h, w = img.shape
    b = det.border
    ins = (x >= b) & (y >= b) & (x < w - b) & (y < h - b)
    return x[ins], y[ins], s[ins]


@pytest.mark.parametrize("patch", [7, 15, 31, 45])
def test_orientation_equals_integral_image_version(astronaut, gravel, patch):
    o = Orientation(patch)
    rng = np.random.default_rng(patch)
    n_total = 0
    for img in (astronaut, gravel, rng.integers(0, 256, (97, 131), dtype=np.uint8),
                np.full((60, 70), 255, np.uint8)):
        h, w = img.shape
        r = patch // 2
        x = rng.integers(r, w - r, 700)
        y = rng.integers(r, h - r, 700)
        got = o(img, x, y)
        ref = _orientation_ref(o, img, x, y)
        assert got.dtype == np.float32 and got.tobytes() == ref.tobytes()
        n_total += len(x)
    assert n_total == 2800


@pytest.mark.parametrize("seed", range(6))
def test_grid_select_equals_two_sort_version(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 3000))
    uv = np.stack([rng.integers(0, 640, n), rng.integers(0, 480, n)], 1).astype(np.float32)
    score = rng.integers(0, [5, 40, 255, 2, 60000, 100][seed], n).astype(np.float32)  # many ties
    for n_keep in (0, 1, n // 7, n // 2, n - 1, n, n + 5):
        got = grid_select(uv, score, 32, n_keep)
        ref = _grid_select_ref(uv, score, 32, n_keep)
        assert got.dtype == np.int64
        np.testing.assert_array_equal(got, ref)
    # non-integer scores and negative coordinates keep the NumPy path: still the same
    uv2 = uv - 100.0
    s2 = score + rng.random(n).astype(np.float32)
    np.testing.assert_array_equal(grid_select(uv2, score, 32, n // 3), _grid_select_ref(uv2, score, 32, n // 3))
    np.testing.assert_array_equal(grid_select(uv, s2, 20, n // 3), _grid_select_ref(uv, s2, 20, n // 3))


@pytest.mark.parametrize("threshold", [0, 1, 10, 25])
def test_fast_on_the_crop_equals_whole_image(astronaut, brick, threshold):
    """FAST on the crop 4 px outside the descriptor border keeps exactly the whole image's corners
    (positions, order, scores), with and without a mask, on every pyramid level."""
    det = OrbGridDetector(FeatureConfig(fast_threshold=max(threshold, 1)))
    det.fast = cv2.FastFeatureDetector_create(threshold=threshold, nonmaxSuppression=True)
    rng = np.random.default_rng(threshold)
    n = 0
    for img in (astronaut, brick):
        for lvl in build_pyramid(img, 8, 1.2):
            m = (rng.random(lvl.shape) < 0.6).astype(np.uint8) * 255
            for mask in (None, m):
                got = det._fast(det.fast, lvl, mask)
                ref = _fast_ref(det, lvl, mask)
                for a, b in zip(got, ref):
                    assert a.dtype == b.dtype and a.tobytes() == b.tobytes()
                n += len(ref[0])
    assert n > 5000


def _detect_ref(det: OrbGridDetector, gray, mask=None):
    """``OrbGridDetector.detect`` as it was: whole-image FAST, the integral-image orientation, the
    two-sort grid selection (single threshold) and OpenCV's descriptors (``cv2.ORB.compute``)."""
    c = det.config
    h0, w0 = gray.shape
    levels = build_pyramid(gray, c.n_levels, c.scale_factor)
    quotas = det.quotas.copy()
    parts = []
    for lvl, img in enumerate(levels):
        h, w = img.shape
        lvl_mask = mask
        if mask is not None and lvl > 0:
            lvl_mask = cv2.resize(mask, (w, h), interpolation=cv2.INTER_NEAREST)
        x, y, score = _fast_ref(det, img, lvl_mask)
        if det.fast_low is not None:  # second threshold in the empty cells (unchanged code)
            cs, b = c.cell_size, det.border
            occupied = np.zeros((-(-h // cs), -(-w // cs)), np.uint8)
            occupied[y // cs, x // cs] = 1
            occupied[: b // cs, :] = 1
            occupied[:, : b // cs] = 1
            occupied[(h - b) // cs + 1 :, :] = 1
            occupied[:, (w - b) // cs + 1 :] = 1
            if not occupied.all():
                x2, y2, s2 = det._fast_in_cells(img, occupied == 0, lvl_mask)
                x, y, score = np.r_[x, x2], np.r_[y, y2], np.r_[score, s2]
        if len(x) == 0:
            continue
        keep = _grid_select_ref(np.stack([x, y], 1).astype(np.float32), score, c.cell_size, int(quotas[lvl]))
        if lvl + 1 < len(quotas):
            quotas[lvl + 1] += max(0, int(quotas[lvl]) - len(keep))
        x, y, score = x[keep], y[keep], score[keep]
        if len(x) == 0:
            continue
        ang = _orientation_ref(det.orientation, img, x, y)
        ids, desc = opencv_orb(img, x, y, ang, c.patch_size, det.border)
        uv = np.stack([(x[ids] + 0.5) * (w0 / w) - 0.5, (y[ids] + 0.5) * (h0 / h) - 0.5], 1)
        parts.append((uv, desc, np.full(len(ids), lvl, np.int32), score[ids], ang[ids]))
    uv, desc, octv, resp, ang = (np.concatenate(z) for z in zip(*parts))
    size = (c.patch_size * np.power(c.scale_factor, octv)).astype(np.float32)
    return (uv.astype(np.float32), np.ascontiguousarray(desc, np.uint8), octv, resp.astype(np.float32),
            ang.astype(np.float32), size)


def _assert_same(feats, ref):
    got = (feats.uv, feats.descriptors, feats.octave, feats.response, feats.angle, feats.size)
    for a, b in zip(got, ref):
        assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


@pytest.mark.parametrize("n_features, min_fast", [(500, 0), (2000, 0), (2000, 5)])
def test_detect_equals_previous_code_path(astronaut, brick, gravel, n_features, min_fast):
    """The whole ORB detector output, array for array, against the previous code path; with a
    mask too (KLT's top-up detection) and with ORB-SLAM's second FAST threshold."""
    det = OrbGridDetector(FeatureConfig(n_features=n_features, min_fast_threshold=min_fast))
    for img in (astronaut, brick, gravel):
        feats = det.detect(img)
        assert len(feats) > 0.9 * n_features
        _assert_same(feats, _detect_ref(det, img))
    mask = np.zeros(astronaut.shape, np.uint8)
    mask[40:400, 100:480] = 255
    _assert_same(det.detect(astronaut, mask), _detect_ref(det, astronaut, mask))


def test_detect_equals_previous_code_path_on_real_frames(shared_data):
    """7-Scenes (640 x 480) and KITTI (1241 x 376) frames: identical Features."""
    det = OrbGridDetector(FeatureConfig())
    paths = [shared_data / "7scenes_redkitchen/seq-xx/frame-000000.color.jpg",
             shared_data / "7scenes_redkitchen/seq-xx/frame-000500.color.jpg",
             shared_data / "kitti_odometry/sequences/06/image_0/000000.png"]
    for p in paths:
        gray = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)
        feats = det.detect(gray)
        assert len(feats) >= 1900
        _assert_same(feats, _detect_ref(det, gray))


def test_orientation_refuses_points_whose_patch_leaves_the_image(astronaut):
    from vslam.errors import VslamError

    o = Orientation(31)
    assert o(astronaut, np.array([15, 496]), np.array([15, 496])).shape == (2,)
    for x, y in ((14, 100), (100, 14), (497, 100), (100, 497)):
        with pytest.raises(VslamError, match="radius 15"):
            o(astronaut, np.array([x]), np.array([y]))
