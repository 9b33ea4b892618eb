"""ORB description of given keypoints: orientation vs OpenCV, which keypoints OpenCV keeps."""
from __future__ import annotations

import cv2
import numpy as np

from tests.features._orb_reference import opencv_orb
from vslam.features.orb_describe import Orientation, describe_orb


def test_orientation_matches_opencv_orb(astronaut):
    """The vectorized intensity-centroid angle equals cv2.ORB's on its own level-0 keypoints."""
    kps = [k for k in cv2.ORB_create(1000).detect(astronaut) if k.octave == 0]
    uv = cv2.KeyPoint_convert(kps).astype(np.int64)
    ref = np.array([k.angle for k in kps])
    ours = Orientation(31)(astronaut, uv[:, 0], uv[:, 1])
    diff = np.abs((ours - ref + 180.0) % 360.0 - 180.0)
    assert len(kps) > 100 and diff.max() < 0.05


def test_describe_orb_equals_opencv_and_keeps_the_input_order():
    """Sub-pixel points, some near or across the border: the kept ones (input order) and their
    descriptors are cv2.ORB.compute's at the rounded pixel with our angle."""
    rng = np.random.default_rng(4)
    img = cv2.GaussianBlur(rng.integers(0, 256, (120, 160), dtype=np.uint8), (5, 5), 1.0)
    uv = np.c_[rng.uniform(10, 150, 400), rng.uniform(10, 110, 400)].astype(np.float32)
    # OpenCV's border test is on the pixel (half to even): 18.5 -> 18 out, 18.51 -> 19 in, 140.5 -> 140
    # in, 140.51 -> 141 = W - 19 out
    uv[:4] = [[18.5, 60], [18.51, 60], [140.5, 60], [140.51, 60]]
    feats = describe_orb(img, uv)
    keep, _ = opencv_orb(img, uv[:, 0], uv[:, 1], np.zeros(len(uv), np.float32))
    assert 150 < len(keep) < 300 and keep[:3].tolist() == [1, 2, 4]
    np.testing.assert_array_equal(feats.uv, uv[keep])
    ref_ids, ref = opencv_orb(img, uv[keep, 0], uv[keep, 1], feats.angle)
    assert len(ref_ids) == len(keep)
    assert feats.descriptors.tobytes() == ref.tobytes()
    # through describe_orb: points near the border are dropped, the rest keep their input order
    img = cv2.GaussianBlur(rng.integers(0, 256, (120, 160), dtype=np.uint8), (5, 5), 1.0)
    uv = np.array([[5, 5], [60, 50], [80, 60], [155, 100], [100, 70]], np.float32)
    feats = describe_orb(img, uv)
    np.testing.assert_array_equal(feats.uv, uv[[1, 2, 4]])
