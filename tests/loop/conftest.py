"""Shared fixtures of the place-recognition tests: ORB descriptors of real frames, computed once."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from vslam.loop.training import extract_orb
from vslam.loop.vocabulary import Vocabulary, load_default_vocabulary

SEVEN_SCENES_FRAMES = sorted(set(range(0, 1000, 10)) | {503, 946})
KITTI07_FRAMES = list(range(0, 160, 2))


@pytest.fixture(scope="session")
def vocabulary() -> Vocabulary:
    return load_default_vocabulary()


@pytest.fixture(scope="session")
def redkitchen(shared_data: Path) -> dict:
    """7-Scenes redkitchen: ORB descriptors and GT poses of frames 0, 10, ..., 990, 503 and 946."""
    root = shared_data / "7scenes_redkitchen" / "seq-xx"
    desc, pose = {}, {}
    for i in SEVEN_SCENES_FRAMES:
        image = cv2.imread(str(root / f"frame-{i:06d}.color.jpg"), cv2.IMREAD_GRAYSCALE)
        assert image is not None, f"cannot read 7-Scenes frame {i}"
        desc[i] = extract_orb(image, 1000)
        pose[i] = np.loadtxt(root / f"frame-{i:06d}.pose.txt")
    return {"descriptors": desc, "T_world_cam": pose}


@pytest.fixture(scope="session")
def kitti07(shared_data: Path) -> dict:
    """KITTI 07 frames 0, 2, ..., 158 (90 m of driving, no loop): ORB descriptors."""
    root = shared_data / "kitti_odometry" / "sequences" / "07" / "image_0"
    desc = {}
    for i in KITTI07_FRAMES:
        image = cv2.imread(str(root / f"{i:06d}.png"), cv2.IMREAD_GRAYSCALE)
        assert image is not None, f"cannot read KITTI 07 frame {i}"
        desc[i] = extract_orb(image, 1000)
    return {"descriptors": desc}
