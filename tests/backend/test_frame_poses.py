"""Frames between keyframes follow the corrected keyframes (vslam.backend.frame_poses)."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
from scipy.spatial.transform import Rotation

from vslam.backend.frame_poses import blend_corrections, frame_poses


def _T(rotvec, t) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
    T[:3, 3] = t
    return T


def _setup(D_a: np.ndarray, D_b: np.ndarray, segment_b: int = 0):
    """Keyframe 0 at t=0 and keyframe 1 at t=1 (moved by D_a / D_b since recorded), five frames at
    t = 0, 0.25, 0.5, 0.75 (referencing keyframe 0) and 1.5 (referencing keyframe 1)."""
    rng = np.random.default_rng(0)
    T_a_rec = _T(rng.normal(size=3) * 0.1, rng.normal(size=3))
    T_b_rec = _T(rng.normal(size=3) * 0.1, rng.normal(size=3))
    kfs = {0: SimpleNamespace(id=0, timestamp=0.0, segment=0, T_world_cam=D_a @ T_a_rec),
           1: SimpleNamespace(id=1, timestamp=1.0, segment=segment_b, T_world_cam=D_b @ T_b_rec)}
    ts = np.array([0.0, 0.25, 0.5, 0.75, 1.5])
    refs = np.array([0, 0, 0, 0, 1])
    T_rec = np.stack([_T(rng.normal(size=3) * 0.1, rng.normal(size=3)) for _ in ts])
    T_ref_rec = np.stack([T_a_rec] * 4 + [T_b_rec])
    return ts, refs, T_rec, T_ref_rec, kfs, {0: T_a_rec, 1: T_b_rec}


def test_no_correction_keeps_tracked_poses():
    ts, refs, T_rec, T_ref_rec, kfs, ins = _setup(np.eye(4), np.eye(4))
    out = frame_poses(ts, refs, T_rec, T_ref_rec, kfs, ins)
    np.testing.assert_allclose(out, T_rec, atol=1e-12)


def test_frames_blend_corrections_of_both_keyframes():
    D_a, D_b = _T([0.0, 0.0, 0.02], [0.01, 0.0, 0.0]), _T([0.0, 0.04, 0.0], [0.0, 0.05, -0.02])
    ts, refs, T_rec, T_ref_rec, kfs, ins = _setup(D_a, D_b)
    out = frame_poses(ts, refs, T_rec, T_ref_rec, kfs, ins)
    # at the reference keyframe's time: its correction; halfway: half the relative correction
    np.testing.assert_allclose(out[0], D_a @ T_rec[0], atol=1e-12)
    rel = np.linalg.inv(D_a) @ D_b
    half = _T(0.5 * Rotation.from_matrix(rel[:3, :3]).as_rotvec(), 0.5 * rel[:3, 3])
    np.testing.assert_allclose(out[2], D_a @ half @ T_rec[2], atol=1e-12)
    # the blend reaches D_b at s = 1
    np.testing.assert_allclose(blend_corrections(D_a[None], D_b[None], np.ones(1))[0], D_b, atol=1e-12)
    # after the last keyframe: rigid with it
    np.testing.assert_allclose(out[4], D_b @ T_rec[4], atol=1e-12)
    # ORB-SLAM's rigid re-expression when asked
    rigid = frame_poses(ts, refs, T_rec, T_ref_rec, kfs, ins, interpolate=False)
    np.testing.assert_allclose(rigid[:4], D_a @ T_rec[:4], atol=1e-12)


def test_no_blending_across_map_segments():
    D_a, D_b = _T([0.0, 0.0, 0.02], [0.01, 0.0, 0.0]), _T([0.0, 0.04, 0.0], [0.0, 0.05, -0.02])
    ts, refs, T_rec, T_ref_rec, kfs, ins = _setup(D_a, D_b, segment_b=1)
    out = frame_poses(ts, refs, T_rec, T_ref_rec, kfs, ins)
    np.testing.assert_allclose(out[:4], D_a @ T_rec[:4], atol=1e-12)


def test_interpolated_frames_lower_ate_on_synthetic_rgbd():
    """Synthetic RGB-D (60 frames, exact ground truth; tests/backend/test_local_mapping.py's sequence):
    with local BA, frames that move rigidly with the keyframe before them leave 6.7 mm ATE; blending
    the corrections of the keyframes on both sides gives 4.8 mm (odometry alone 18.0 mm; with the
    disparity RGB-D residual 5.7 -> 4.0 mm)."""
    import importlib.util
    from pathlib import Path

    from vslam.config import BackendConfig

    spec = importlib.util.spec_from_file_location("_tlm", Path(__file__).with_name("test_local_mapping.py"))
    tlm = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tlm)
    _, _, gt = tlm._sequence()
    system, _ = tlm._ba_run()
    assert system._backend_cfg.frame_correction == "interpolate"
    ate_interp = tlm._ate(system.trajectory(), gt)
    cfg = system._backend_cfg
    system._backend_cfg = BackendConfig(frame_correction="reference")  # same run, ORB-SLAM's re-expression
    try:
        ate_ref = tlm._ate(system.trajectory(), gt)
    finally:
        system._backend_cfg = cfg
    assert ate_ref > 0.006  # measured 0.0067
    assert ate_interp < 0.0055  # measured 0.0048
