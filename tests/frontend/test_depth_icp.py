"""Depth-image ICP (the tracker's RGB-D fallback when features give no pose)."""
from __future__ import annotations

import numpy as np
import pytest

from vslam.datasets.synthetic import SyntheticConfig, SyntheticSequence
from vslam.frontend.depth_icp import align_depth, depth_agreement


def _inv(T: np.ndarray) -> np.ndarray:
    return np.linalg.inv(T)


def _error(T: np.ndarray, T_true: np.ndarray) -> tuple[float, float]:
    d = _inv(T_true) @ T
    ang = np.degrees(np.arccos(np.clip((np.trace(d[:3, :3]) - 1) / 2, -1, 1)))
    return float(np.linalg.norm(T[:3, 3] - T_true[:3, 3])), float(ang)


@pytest.fixture(scope="module")
def room():
    """The synthetic textured room with exact depth: ~2.5 deg and 6 cm per frame."""
    return SyntheticSequence(SyntheticConfig(n_frames=150, laps=1.2, seed=0, width=320, height=240,
                                             fx=262.5, fy=262.5, cx=159.5, cy=119.5))


def test_icp_recovers_a_wide_step_from_identity(room):
    a, b = room[0], room[2]
    T_true = _inv(a.T_world_cam) @ b.T_world_cam  # T_prev_cur: 12 cm, 5 deg
    assert _error(np.eye(4), T_true)[1] > 4.5
    T, agree = align_depth(a.depth, b.depth, a.camera.K, np.eye(4))
    assert T is not None
    dist, ang = _error(T, T_true)
    assert dist < 0.002 and ang < 0.05, (dist, ang)
    assert agree > 0.95


def test_icp_from_a_prediction_on_a_wider_step(room):
    a, b = room[0], room[6]
    T_true = _inv(a.T_world_cam) @ b.T_world_cam  # 37 cm, 15 deg
    # a constant-velocity prediction that is off by a third of the step
    T_guess = _inv(a.T_world_cam) @ room[4].T_world_cam
    T, _ = align_depth(a.depth, b.depth, a.camera.K, T_guess)
    assert T is not None
    dist, ang = _error(T, T_true)
    assert dist < 0.01 and ang < 0.2, (dist, ang)


def test_agreement_separates_right_and_wrong_poses(room):
    a, b = room[0], room[8]
    T_true = _inv(a.T_world_cam) @ b.T_world_cam
    right = depth_agreement(a.depth, b.depth, a.camera.K, T_true)
    wrong = depth_agreement(a.depth, b.depth, a.camera.K, np.eye(4))
    assert right > 0.95
    assert wrong < 0.5


def test_no_overlap_gives_no_agreement(room):
    a = room[0]
    T_behind = np.eye(4)
    T_behind[:3, :3] = np.diag([-1.0, 1.0, -1.0])  # looking backwards: nothing projects into frame a
    assert depth_agreement(a.depth, a.depth, a.camera.K, T_behind) == 0.0


def test_photometric_variant_on_the_same_step(room):
    a, b = room[0], room[2]
    T_true = _inv(a.T_world_cam) @ b.T_world_cam
    T, agree = align_depth(a.depth, b.depth, a.camera.K, np.eye(4), gray_prev=a.gray, gray_cur=b.gray)
    assert T is not None and agree > 0.95
    dist, ang = _error(T, T_true)
    assert dist < 0.005 and ang < 0.1, (dist, ang)


def test_downsampled_alignment_keeps_the_full_resolution_accuracy(room):
    """``downsample=2`` (the tracker's dense refinement): half-resolution images, K halved, the
    agreement still measured on the full images."""
    a, b = room[0], room[2]
    T_true = _inv(a.T_world_cam) @ b.T_world_cam
    T, agree = align_depth(a.depth, b.depth, a.camera.K, np.eye(4), gray_prev=a.gray, gray_cur=b.gray, downsample=2)
    assert T is not None and agree > 0.95
    dist, ang = _error(T, T_true)
    assert dist < 0.005 and ang < 0.1, (dist, ang)
    # and the same result as at full resolution (an unscaled K would put it centimetres off)
    T_full, _ = align_depth(a.depth, b.depth, a.camera.K, np.eye(4), gray_prev=a.gray, gray_cur=b.gray)
    assert _error(T, T_full)[0] < 0.005
