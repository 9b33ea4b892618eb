"""Local mapping (windowed BA + culling), final global BA and the EKF backend plugged into System.

Synthetic RGB-D (exact ground truth, 1 grey-level pixel noise, 2 % depth noise): the frontend alone
drifts ~18 mm over 60 frames; with local BA ~7 mm (measured, see the asserts).
"""
from __future__ import annotations

import functools

import numpy as np
import pytest

from vslam.backend.local_mapping import LocalMapper
from vslam.config import BackendConfig, Config
from vslam.datasets.synthetic.sequence import SyntheticConfig, SyntheticSequence
from vslam.eval.trajectory import Trajectory
from vslam.geometry.umeyama import umeyama
from vslam.loop.config import LoopConfig
from vslam.system import System


@functools.lru_cache(maxsize=1)
def _sequence():
    cfg = SyntheticConfig(n_frames=60, laps=0.2, width=320, height=240, fx=262.5, fy=262.5, cx=159.5, cy=119.5,
                          pixel_noise=1.0, depth_noise=0.02, depth_noise_model="proportional", seed=3)
    seq = SyntheticSequence(cfg)
    return seq.camera, list(seq), seq.ground_truth()


def _ate(est: Trajectory, gt: Trajectory) -> float:
    idx = np.clip(np.searchsorted(gt.timestamps, est.timestamps), 0, len(gt) - 1)
    assert np.all(np.abs(gt.timestamps[idx] - est.timestamps) < 1e-3)
    P, Q = est.positions, gt.positions[idx]
    R, t, s = umeyama(P, Q, with_scale=False)
    return float(np.sqrt(((Q - (P @ R.T + t)) ** 2).sum(axis=1).mean()))


def _run(backend: BackendConfig, n_frames: int | None = None) -> tuple[System, Trajectory]:
    camera, frames, _ = _sequence()
    system = System(Config(backend=backend, loop=LoopConfig(enabled=False)), camera, "rgbd")
    for frame in frames[:n_frames]:
        system.track(frame)
    before = system.trajectory()
    system.finish()
    return system, before


@functools.lru_cache(maxsize=None)
def _ba_run() -> tuple[System, Trajectory]:
    return _run(BackendConfig())


def test_local_ba_lowers_ate_on_synthetic_rgbd():
    _, _, gt = _sequence()
    base, _ = _run(BackendConfig(local_ba=False))
    ba, _ = _ba_run()
    ate_base, ate_ba = _ate(base.trajectory(), gt), _ate(ba.trajectory(), gt)
    assert len(ba.trajectory()) == len(gt)
    assert ate_base > 0.012  # measured 0.0180
    assert ate_ba < 0.009  # measured 0.0067
    assert ate_ba < 0.6 * ate_base
    st = ba.stats()
    assert st["backend"]["local_ba_calls"] == st["keyframes"] >= 5
    assert 0 < st["stage_ms"]["local_ba"] < 5000
    assert base.stats()["backend"]["local_ba_calls"] == 0


def test_deterministic_mode_repeats_and_final_ba_runs():
    _, _, gt = _sequence()
    first, _ = _ba_run()
    # the same configuration plus final_ba: the trajectory before finish() must be identical bit for bit
    second, before_final = _run(BackendConfig(final_ba=True))
    a = first.trajectory()
    np.testing.assert_array_equal(a.timestamps, before_final.timestamps)
    np.testing.assert_array_equal(a.T_world_cam, before_final.T_world_cam)
    final = second.stats()["backend"]["global_ba"]
    assert second.stats()["backend"]["global_ba_calls"] == 1
    assert final["keyframes"] == second.stats()["keyframes"]
    assert final["final_rms_px"] <= final["initial_rms_px"] + 1e-9
    # the first keyframe is the gauge: it never moves
    kf0 = second.map.keyframes[0]
    np.testing.assert_array_equal(kf0.T_world_cam, np.eye(4))
    assert _ate(second.trajectory(), gt) < 0.009


def test_ekf_backend_filters_every_tracked_pose():
    n = 30
    system, _ = _run(BackendConfig(type="ekf"), n)
    traj = system.trajectory()
    assert len(traj) == n
    st = system.stats()["backend"]
    assert st["type"] == "ekf" and st["updates"] == n
    assert 0 < st["mean_correction_m"] < 0.005  # the filter moves the poses, but only a little
    assert _ate(traj, _sequence()[2]) < 0.008  # measured 0.0046 (the frontend alone: 0.0046)
    assert system.local_mapper is None


def test_realtime_mode_tracks_every_frame():
    n = 30
    system, _ = _run(BackendConfig(mode="realtime"), n)
    traj = system.trajectory()
    st = system.stats()["backend"]
    assert len(traj) == n
    assert st["mode"] == "realtime" and st["failed"] == 0
    assert st["local_ba_calls"] + st["local_ba_skipped"] == system.stats()["keyframes"]
    assert _ate(traj, _sequence()[2]) < 0.009  # not bit-reproducible: a bound (measured 0.0049)


def test_window_fixes_gauge_for_monocular():
    """The first keyframe is always constant, and a monocular window holds two constant keyframes."""
    system, _ = _ba_run()
    mapper = LocalMapper(system.map, system.camera, "mono", BackendConfig())
    newest = system.map.keyframes[max(system.map.keyframes)]
    window, fixed = mapper._window(newest)
    assert len(fixed) >= 2 and not set(window) & set(fixed)
    first = system.map.keyframes[min(system.map.keyframes)]
    w0, f0 = mapper._window(system.map.keyframes[1])
    assert first.id in f0 and first.id not in w0


@pytest.mark.shared
def test_kitti06_stereo_local_ba(shared_data):
    """Real data: KITTI 06 (51 frames, stereo). Frontend alone 0.165 m ATE; with local BA 0.12 m
    (the remaining error is a 0.7 % scale error of the frontend's stereo depth: Sim(3) ATE 0.03 m).
    The 0.06 m goal is not reached; this asserts what is achieved."""
    from vslam.datasets import open_dataset

    ds = open_dataset(shared_data / "kitti_odometry" / "sequences" / "06", sensor="stereo")
    system = System(Config(loop=LoopConfig(enabled=False)), ds.camera, "stereo")
    for frame in ds:
        system.track(frame)
    system.finish()
    traj = system.trajectory()
    assert len(traj) == 51
    assert _ate(traj, ds.ground_truth()) < 0.145


def test_culled_keyframe_follows_its_parent():
    """A keyframe flagged bad (KeyFrameCulling) keeps a pose: it moves rigidly with its parent, and so
    do the frames that reference it in System.trajectory()."""
    system, _ = _run(BackendConfig(), 30)
    mapper = system.local_mapper
    ids = sorted(system.map.keyframes)
    victim = system.map.keyframes[ids[len(ids) // 2]]
    before = system.trajectory()
    mapper._set_bad(victim)
    assert victim.bad and mapper.counts["culled_keyframes"] == 1
    assert victim.id not in system.map.covisibility.get(victim.extra["parent"], {})
    parent = system.map.keyframes[victim.extra["parent"]]
    T_parent_victim = np.linalg.inv(parent.T_world_cam) @ victim.T_world_cam
    shift = np.eye(4)
    shift[:3, 3] = [0.1, 0.0, 0.0]
    parent.T_world_cam = shift @ parent.T_world_cam
    mapper._update_bad_keyframes()
    np.testing.assert_allclose(victim.T_world_cam, parent.T_world_cam @ T_parent_victim, atol=1e-12)
    after = system.trajectory()
    moved = np.linalg.norm(after.positions - before.positions, axis=1)
    assert np.all((np.abs(moved) < 1e-9) | (np.abs(moved - 0.1) < 1e-9))
    assert np.sum(np.abs(moved - 0.1) < 1e-9) >= 1
