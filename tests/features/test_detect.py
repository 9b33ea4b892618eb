"""Feature detection: counts, spatial spread, orientation vs OpenCV, the other detectors."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from vslam.errors import ConfigError, VslamError
from vslam.features import FeatureConfig, Features, create_detector


def cell_coverage(uv: np.ndarray, shape: tuple[int, int], cell: int, margin: int) -> float:
    """Fraction of ``cell``-pixel grid cells (inside ``margin``) holding at least one point."""
    h, w = shape
    ny, nx = (h - 2 * margin) // cell, (w - 2 * margin) // cell
    occ = np.zeros((ny, nx), bool)
    q = ((uv - margin) // cell).astype(int)
    inside = (q[:, 0] >= 0) & (q[:, 1] >= 0) & (q[:, 0] < nx) & (q[:, 1] < ny)
    occ[q[inside, 1], q[inside, 0]] = True
    return float(occ.mean())


def test_orb_count_and_spread_on_texture(brick):
    feats = create_detector(FeatureConfig(n_features=1500)).detect(brick)
    assert 1350 <= len(feats) <= 1500
    assert feats.uv.dtype == np.float32 and feats.uv.shape == (len(feats), 2)
    assert feats.descriptors.dtype == np.uint8 and feats.descriptors.shape == (len(feats), 32)
    assert feats.binary and feats.scale_factor == pytest.approx(1.2)
    assert coverage_ok(feats, brick.shape, 0.8)
    # every pyramid level contributes, finer levels more (geometric quota)
    counts = np.bincount(feats.octave, minlength=8)
    assert (counts > 0).all() and counts[0] > counts[7]
    # sizes follow the level scale
    np.testing.assert_allclose(feats.size, 31 * 1.2 ** feats.octave, rtol=1e-5)


def coverage_ok(feats: Features, shape, at_least: float) -> bool:
    cov = cell_coverage(feats.uv, shape, 32, 19)
    return cov >= at_least


def test_orb_spread_beats_plain_opencv_orb(astronaut):
    """Plain cv2.ORB clusters on strong texture; the grid spreads features over more cells."""
    ours = create_detector(FeatureConfig(n_features=1000)).detect(astronaut)
    plain = cv2.KeyPoint_convert(cv2.ORB_create(1000).detect(astronaut))
    assert cell_coverage(ours.uv, astronaut.shape, 32, 19) > cell_coverage(plain, astronaut.shape, 32, 19) + 0.1


@pytest.mark.shared
def test_orb_on_kitti_frame(shared_data):
    path = shared_data / "kitti_odometry/sequences/06/image_0/000000.png"
    gray = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    feats = create_detector(FeatureConfig(n_features=2000)).detect(gray)
    assert 1900 <= len(feats) <= 2000
    assert cell_coverage(feats.uv, gray.shape, 40, 19) >= 0.8
    assert (feats.uv[:, 0] >= 0).all() and (feats.uv[:, 0] < gray.shape[1]).all()
    assert (feats.uv[:, 1] >= 0).all() and (feats.uv[:, 1] < gray.shape[0]).all()


def test_descriptors_are_rotation_invariant(brick):
    """A 90-degree rotation keeps the descriptors: same corners match with small distances."""
    det = create_detector(FeatureConfig(n_features=800))
    f0 = det.detect(brick)
    rot = cv2.rotate(brick, cv2.ROTATE_90_CLOCKWISE)
    f1 = det.detect(rot)
    h = brick.shape[0]
    # (u, v) -> (h - 1 - v, u) under a clockwise rotation
    moved = np.c_[h - 1 - f0.uv[:, 1], f0.uv[:, 0]]
    from scipy.spatial import cKDTree

    d, j = cKDTree(f1.uv).query(moved)
    same = (d < 1.0) & (f1.octave[j] == f0.octave) & (f0.octave == 0)
    assert same.sum() > 50
    ham = np.bitwise_count(f0.descriptors[same] ^ f1.descriptors[j[same]]).sum(1)
    assert np.median(ham) < 30


def test_mask_is_respected(brick):
    mask = np.zeros_like(brick)
    mask[:, 256:] = 255
    feats = create_detector(FeatureConfig(n_features=500)).detect(brick, mask)
    assert len(feats) > 300 and (feats.uv[:, 0] >= 250).all()


@pytest.mark.parametrize("name,binary,dim", [("sift", False, 128), ("akaze", True, 61),
                                              ("brisk", True, 64), ("gftt_orb", True, 32)])
def test_other_detectors(astronaut, name, binary, dim):
    feats = create_detector(FeatureConfig(detector=name, n_features=800)).detect(astronaut)
    assert 200 <= len(feats) <= 800
    assert feats.binary is binary
    assert feats.descriptors.shape == (len(feats), dim)
    assert feats.descriptors.dtype == (np.uint8 if binary else np.float32)
    assert (feats.octave >= 0).all() and len(feats.angle) == len(feats.response) == len(feats.size) == len(feats)


def test_bad_inputs():
    with pytest.raises(ConfigError, match="detector"):
        FeatureConfig(detector="surf")
    with pytest.raises(ConfigError):
        FeatureConfig(scale_factor=1.0)
    det = create_detector(FeatureConfig())
    with pytest.raises(VslamError, match="uint8"):
        det.detect(np.zeros((100, 100), np.float32))
    assert len(det.detect(np.zeros((100, 120), np.uint8))) == 0


def test_two_threshold_fast_fills_weak_cells(astronaut):
    """ORB-SLAM's 20/7 scheme: the second, low-threshold pass only adds corners in cells the
    first pass left empty, so coverage rises over a single pass at 20."""
    single = create_detector(FeatureConfig(n_features=1500, fast_threshold=20)).detect(astronaut)
    double = create_detector(FeatureConfig(n_features=1500, fast_threshold=20, min_fast_threshold=7)).detect(astronaut)
    cov1 = cell_coverage(single.uv, astronaut.shape, 32, 19)
    cov2 = cell_coverage(double.uv, astronaut.shape, 32, 19)
    assert cov2 > cov1 + 0.05
    # strong corners stay: most single-pass level-0 corners with score >= 40 are kept (the new
    # weak-cell corners take some of the fixed quota from the strong cells' later rounds)
    strong = single.uv[(single.octave == 0) & (single.response >= 40)]
    d = np.linalg.norm(strong[:, None] - double.uv[None, double.octave == 0], axis=2).min(1)
    assert len(strong) > 20 and (d < 0.5).mean() > 0.8


def test_descriptors_equal_opencv_multilevel_orb(astronaut):
    """Per-level description on our pyramid gives exactly OpenCV ORB's descriptors for the same
    keypoints (so ORB vocabularies trained on OpenCV/ORB-SLAM descriptors apply)."""
    from vslam.features import build_pyramid

    feats = create_detector(FeatureConfig(n_features=800)).detect(astronaut)
    levels = build_pyramid(astronaut, 8, 1.2)
    h0, w0 = astronaut.shape
    kps = []
    for i, (u, v, o, a) in enumerate(zip(feats.uv[:, 0], feats.uv[:, 1], feats.octave, feats.angle)):
        hl, wl = levels[o].shape
        s = 1.2 ** int(o)
        x, y = round((u + 0.5) * wl / w0 - 0.5), round((v + 0.5) * hl / h0 - 0.5)  # level pixel
        kps.append(cv2.KeyPoint(x * s, y * s, 31 * s, float(a), 0, int(o), i))
    out, desc = cv2.ORB_create(800, 1.2, 8, edgeThreshold=19, patchSize=31).compute(astronaut, kps)
    ids = np.array([k.class_id for k in out])
    assert len(ids) == len(feats) and (feats.octave > 0).sum() > 300
    np.testing.assert_array_equal(desc, feats.descriptors[ids])
