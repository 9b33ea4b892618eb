"""ORB description of given keypoints: orientation vs OpenCV, which keypoints OpenCV keeps."""
from __future__ import annotations

import cv2
import numpy as np

from vslam.features.orb_describe import Orientation, describe_orb, make_keypoints, survivors


def test_orientation_matches_opencv_orb(astronaut):
    """The vectorized intensity-centroid angle equals cv2.ORB's on its own level-0 keypoints."""
    kps = [k for k in cv2.ORB_create(1000).detect(astronaut) if k.octave == 0]
    uv = cv2.KeyPoint_convert(kps).astype(np.int64)
    ref = np.array([k.angle for k in kps])
    ours = Orientation(31)(astronaut, uv[:, 0], uv[:, 1])
    diff = np.abs((ours - ref + 180.0) % 360.0 - 180.0)
    assert len(kps) > 100 and diff.max() < 0.05


def test_survivors_finds_the_kept_keypoints_in_order():
    """cv2.ORB.compute may drop keypoints (order-preserving); their input indices are recovered
    from the positions, duplicates included."""
    rng = np.random.default_rng(4)
    x = rng.integers(0, 100, 50).astype(np.float64)
    y = rng.integers(0, 80, 50).astype(np.float64)
    x[7], y[7] = x[6], y[6]  # a duplicated position
    kps = make_keypoints(x, y, rng.uniform(0, 360, 50), 31.0)
    np.testing.assert_array_equal(survivors(kps, x, y), np.arange(50))
    keep = np.sort(rng.choice(50, 30, replace=False))
    keep = np.union1d(keep, [6, 7])
    out = [kps[i] for i in keep]
    np.testing.assert_array_equal(survivors(out, x, y), keep)
    # through describe_orb: points near the border are dropped, the rest keep their input order
    img = cv2.GaussianBlur(rng.integers(0, 256, (120, 160), dtype=np.uint8), (5, 5), 1.0)
    uv = np.array([[5, 5], [60, 50], [80, 60], [155, 100], [100, 70]], np.float32)
    feats = describe_orb(img, uv)
    np.testing.assert_array_equal(feats.uv, uv[[1, 2, 4]])
