"""The compiled rotated-BRIEF descriptors (vslam.features.orb_describe_kernels through
``RotatedBrief``) against ``cv2.ORB.compute``: the same kept keypoints and the same bytes."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from tests.features._orb_reference import opencv_orb
from vslam.features.config import FeatureConfig
from vslam.features.detect import OrbGridDetector
from vslam.features.orb_describe import RotatedBrief
from vslam.features.orb_pattern import PAIRS_31
from vslam.features.pyramid import build_pyramid

# angles where cos or sin is (nearly) 0 or +-1 or the rotation lands near half pixels
_SPECIAL = np.array([0, 90, 180, 270, 45, 135, 225, 315, 359.99998, 1e-6, 30, 60, 89.99999, 90.00001,
                     179.99998, 270.00003, 15, 75, 105, 345], np.float32)


def _random_keypoints(shape, n, seed):
    rng = np.random.default_rng(seed)
    h, w = shape
    x = rng.integers(0, w, n)
    y = rng.integers(0, h, n)
    ang = rng.uniform(0.0, 360.0, n).astype(np.float32)
    ang[: len(_SPECIAL)] = _SPECIAL
    return x, y, ang


def _check(brief: RotatedBrief, img, x, y, ang, patch_size, border):
    keep = brief.inside(x, y, img.shape)
    ids, ref = opencv_orb(img, x, y, ang, patch_size, border)
    np.testing.assert_array_equal(np.flatnonzero(keep), ids)
    ours = brief.describe(brief.smooth(img), x[keep], y[keep], ang[keep])
    assert ours.shape == ref.shape and ours.dtype == np.uint8
    bad = np.flatnonzero((ours != ref).any(1))
    assert len(bad) == 0, f"{len(bad)} of {len(ref)} differ, first at {x[keep][bad[:3]]}, {y[keep][bad[:3]]}"
    return len(ids)


def test_pattern_is_the_learned_31x31_one():
    """256 distinct pairs inside the 31 x 31 patch (|offset| <= 13), two distinct points each."""
    assert PAIRS_31.shape == (256, 4) and np.abs(PAIRS_31).max() == 13
    assert len({tuple(r) for r in PAIRS_31.tolist()}) == 256
    assert not (PAIRS_31[:, :2] == PAIRS_31[:, 2:]).all(1).any()
    assert PAIRS_31[0].tolist() == [8, -3, 9, 5] and PAIRS_31[-1].tolist() == [-1, -6, 0, -11]


@pytest.mark.parametrize("name", ["astronaut", "brick", "gravel", "noise"])
def test_descriptors_equal_opencv_on_textures(request, name):
    """Random integer keypoints all over the image (about a fifth dropped by the border) with
    random and special angles: identical kept set and descriptors."""
    if name == "noise":
        img = np.random.default_rng(3).integers(0, 256, (300, 417), dtype=np.uint8)
    else:
        img = request.getfixturevalue(name)
    brief = RotatedBrief(31, 19)
    assert brief.pad == 0 and brief.reach == 18
    x, y, ang = _random_keypoints(img.shape, 6000, seed=len(name))
    n = _check(brief, img, x, y, ang, 31, 19)
    assert 3500 < n < 5500


@pytest.mark.parametrize("patch_size, border", [(31, 16), (31, 24), (15, 8), (21, 11), (41, 21)])
def test_other_patch_sizes_and_borders(astronaut, patch_size, border):
    """OpenCV's random pattern for patch sizes other than 31, and borders narrower than the
    pattern's reach (samples in OpenCV's unsmoothed reflect-101 padding)."""
    brief = RotatedBrief(patch_size, border)
    assert brief.pad == max(0, brief.reach - border)
    x, y, ang = _random_keypoints(astronaut.shape, 3000, seed=patch_size + border)
    assert _check(brief, astronaut, x, y, ang, patch_size, border) > 2000


def test_describe_refuses_centres_whose_pattern_leaves_the_image():
    from vslam.errors import VslamError

    brief = RotatedBrief(31, 19)
    img = np.zeros((60, 60), np.uint8)
    with pytest.raises(VslamError):
        brief.describe(brief.smooth(img), np.array([17]), np.array([30]), np.zeros(1, np.float32))


def test_descriptors_equal_opencv_on_real_frames_at_every_level(shared_data):
    """7-Scenes (640 x 480) and KITTI 06 (1241 x 376): the detector's own keypoints and angles on
    every pyramid level, described by us and by cv2.ORB.compute."""
    det = OrbGridDetector(FeatureConfig())
    c = det.config
    paths = [shared_data / "7scenes_redkitchen/seq-xx/frame-000000.color.jpg",
             shared_data / "7scenes_redkitchen/seq-xx/frame-000900.color.jpg",
             shared_data / "kitti_odometry/sequences/06/image_0/000000.png",
             shared_data / "kitti_odometry/sequences/06/image_0/000050.png"]
    n = 0
    for p in paths:
        gray = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)
        assert gray is not None, p
        levels = build_pyramid(gray, c.n_levels, c.scale_factor)
        n_levels = 0
        for img, cand in zip(levels, det.candidates(levels, None)):
            if cand is None:
                continue
            x, y, _ = cand
            ang = det.orientation(img, x, y)
            n += _check(det.brief, img, x, y, ang, c.patch_size, det.border)
            n_levels += 1
        assert n_levels == c.n_levels
    assert n == len(paths) * c.n_features  # every frame fills its quota; the border drops none
