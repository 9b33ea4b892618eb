"""Local mapping (windowed BA + culling), final global BA and the EKF backend plugged into System.

Synthetic RGB-D (exact ground truth, 1 grey-level pixel noise, 2 % depth noise): the frontend alone
drifts ~18 mm over 60 frames; with local BA ~5 mm (measured, see the asserts).
"""
from __future__ import annotations

import functools

import numpy as np
import pytest

from vslam.backend.config import MonoBAConfig
from vslam.backend.local_mapping import LocalMapper
from vslam.config import BackendConfig, Config
from vslam.datasets.synthetic.sequence import SyntheticConfig, SyntheticSequence
from vslam.features.config import FeatureConfig
from vslam.trajectory import Trajectory
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
    # integer FAST corners, as when these figures were measured: with the sub-pixel keypoints (the RGB-D default
    # since issue 24) this synthetic 320x240 run measures the opposite way round (9 keyframes: odometry 0.0035 m,
    # local BA 0.0041 m; real RGB-D rows all improve with them, benchmarks/RESULTS.md)
    system = System(Config(features=FeatureConfig(subpixel="off"), backend=backend, loop=LoopConfig(enabled=False)),
                    camera, "rgbd")
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
    assert ate_ba < 0.0055  # measured 0.0042 (u_right residual 0.0049, 0.0067 with rigid frames; disparity scale 1 0.0040)
    assert ate_ba < 0.6 * ate_base
    st = ba.stats()
    assert st["backend"]["local_ba_calls"] == st["keyframes"] >= 5
    assert 0 < st["stage_ms"]["local_ba"] < 5000
    assert base.stats()["backend"]["local_ba_calls"] == 0


def test_local_ba_helps_from_the_second_keyframe_on_synthetic_rgbd():
    """The first 9 and 15 frames (2 and 3 keyframes), exact ground truth, ATE mm: odometry 2.82 / 3.47,
    local BA with the disparity residual for the depth (``disparity_sigma_scale`` 1) 2.42 / 2.82. With
    ORB-SLAM2's u_right residual (errors on u and on u_right independent: u counted twice, the depth
    error tied to u's) the BA of the second keyframe moved it from 7.3 to 24 mm error (Mahalanobis^2 67
    under its own covariance) and the ATE is 6.7 / 4.9 mm (11.5 / 6.3 with rigid frames); with the
    disparity residual that keyframe is at 6.2 mm. The default (disparity, scale sqrt 2: u_right's
    depth weight, for real sensors' unregistered depth) gives 3.68 / 3.50 here (30 / 60 frames: 2.97 /
    4.20, odometry 4.66 / 18.1): the synthetic depth is as exact as the pixels."""
    from vslam.backend.config import LocalBAConfig

    _, _, gt = _sequence()
    for n, measured in ((9, 0.00242), (15, 0.00282)):
        odo, _ = _run(BackendConfig(local_ba=False), n)
        ba, _ = _run(BackendConfig(local=LocalBAConfig(rgbd_residual="disparity", disparity_sigma_scale=1.0)), n)
        ate_odo, ate_ba = _ate(odo.trajectory(), gt), _ate(ba.trajectory(), gt)
        assert ate_ba < ate_odo - 0.0003, (n, ate_odo, ate_ba)
        assert ate_ba < measured + 0.0004, (n, ate_ba)


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
    do the frames that reference it in System.trajectory() (``frame_correction="reference"``; with the
    default ``interpolate`` the frames between keyframes blend the corrections, test_frame_poses.py)."""
    system, _ = _run(BackendConfig(frame_correction="reference"), 30)
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


def _mono_problem(**overrides):
    system, _ = _ba_run()
    cfg = BackendConfig(**overrides)
    mapper = LocalMapper(system.map, system.camera, "mono", cfg)
    newest = max(system.map.keyframes)
    window, fixed = mapper._window(system.map.keyframes[newest])
    problem, _ = mapper._problem(window, fixed, system.map.local_point_ids(window), newest)
    return problem


def test_monocular_ba_leaves_out_two_view_points():
    """Monocular local BA keeps only points seen by >= mono.min_observations keyframes (the default
    3: no two-view points, whose depth BA pushes outwards); with 2 every point enters, and so it
    does while too few multi-view points exist (the first windows)."""
    every = _mono_problem(mono=MonoBAConfig(min_observations=2))
    n_every = np.bincount(every.pt_index(every.obs_pt))
    assert np.sum(n_every == 2) > 50  # the synthetic map has many two-view points
    kept = _mono_problem()
    n_kept = np.bincount(kept.pt_index(kept.obs_pt))
    assert n_kept.min() >= 3 and kept.num_points >= 100
    assert set(kept.pt_ids) < set(every.pt_ids)
    assert kept.num_points == every.num_points - np.sum(n_every == 2)
    few = _mono_problem(mono=MonoBAConfig(min_multiview_points=10**6))
    assert few.num_points == every.num_points
    # RGB-D / stereo problems are untouched (a depth observation determines a point)
    system, _ = _ba_run()
    mapper = LocalMapper(system.map, system.camera, "rgbd", BackendConfig())
    newest = max(system.map.keyframes)
    window, fixed = mapper._window(system.map.keyframes[newest])
    rgbd, _ = mapper._problem(window, fixed, system.map.local_point_ids(window), newest)
    assert rgbd.num_points >= every.num_points


def test_monocular_retriangulate_left_out_points():
    """``mono.left_out=retriangulate``: the two-view points left out of BA are triangulated again from their
    two observations with the (corrected) poses; on the synthetic map they land within a few
    percent of their depth of where they were and reproject onto both observations."""
    system, _ = _ba_run()
    mapper = LocalMapper(system.map, system.camera, "mono", BackendConfig(mono=MonoBAConfig(left_out="retriangulate")))
    newest = max(system.map.keyframes)
    window, fixed = mapper._window(system.map.keyframes[newest])
    problem, ctx = mapper._problem(window, fixed, system.map.local_point_ids(window), newest)
    pt, kf, uv = ctx.left_out
    ids = np.unique(pt)
    assert len(ids) > 50 and not set(ids.tolist()) & set(problem.pt_ids.tolist())
    store = system.map.points
    saved = store.position.copy()
    try:
        store.position[ids] += 0.05  # stale positions
        mapper._retriangulate_left_out(pt, kf, uv, {k: np.eye(4) for k in window})
        new = store.position[ids].copy()
    finally:
        store.position[:] = saved
    T = np.stack([system.map.keyframes[k].T_cam_world for k in kf.tolist()])
    X = new[np.searchsorted(ids, pt)]
    Xc = np.einsum("nij,nj->ni", T[:, :3, :3], X) + T[:, :3, 3]
    proj = Xc[:, :2] / Xc[:, 2:] * [system.camera.fx, system.camera.fy] + [system.camera.cx, system.camera.cy]
    err = np.linalg.norm(proj - uv, axis=1)
    assert np.median(err) < 1.0 and np.all(Xc[:, 2] > 0)
    depth = np.linalg.norm(saved[ids] - system.map.keyframes[newest].T_world_cam[:3, 3], axis=1)
    assert np.median(np.linalg.norm(new - saved[ids], axis=1) / depth) < 0.05


def _mono_ate(path, backend: BackendConfig) -> tuple[float, int]:
    """Sim(3)-aligned ATE of a monocular run over the whole sequence, and the number of posed frames."""
    from vslam.datasets import open_dataset

    ds = open_dataset(path, sensor="mono")
    gt = ds.ground_truth()
    system = System(Config(backend=backend, loop=LoopConfig(enabled=False)), ds.camera, "mono")
    for frame in ds:
        system.track(frame)
    system.finish()
    traj = system.trajectory()
    idx = np.clip(np.searchsorted(gt.timestamps, traj.timestamps), 0, len(gt) - 1)
    P, Q = traj.positions, gt.positions[idx]
    R, t, s = umeyama(P, Q, with_scale=True)
    return float(np.sqrt(((Q - (s * P @ R.T + t)) ** 2).sum(axis=1).mean())), len(traj)


@pytest.mark.shared
def test_kitti_monocular_local_ba(shared_data):
    """Real data, monocular, Sim(3) ATE. KITTI 07 (160 frames): local BA used to make it much worse
    (odometry 0.276 m, local BA 0.431 m; fusion and two-view points in BA fed scale drift through
    the two turns), now 0.385 m (``mono.left_out=retriangulate``; 0.290 with ``keep``, whose
    frames saw-tooth). Every frame gets a pose (the frames before the initialization are localized
    afterwards). KITTI 06 (51 frames): odometry 0.246 m, local BA 0.04-0.05 m."""
    seqs = shared_data / "kitti_odometry" / "sequences"
    ate_ba, n_ba = _mono_ate(seqs / "07", BackendConfig())
    assert n_ba == 160
    assert ate_ba < 0.41
    ate_odo6, _ = _mono_ate(seqs / "06", BackendConfig(local_ba=False))
    ate_ba6, n6 = _mono_ate(seqs / "06", BackendConfig())
    assert n6 == 51
    assert ate_ba6 < 0.08 and ate_ba6 < 0.5 * ate_odo6


def _euroc_second_keyframe_ba(shared_data, monkeypatch, backend: BackendConfig):
    """The local BA problem of the second keyframe (frame 20) of EuRoC V1_01 (stereo, at rest), with
    the 2-D LK stereo matcher (the default before the row matcher): it leaves far keypoints without
    depth, which this scenario needs; the row matcher gives most of them a depth."""
    import vslam.backend.local_mapping as lm
    from vslam.datasets import open_dataset
    from vslam.frontend.config import DepthConfig, FrontendConfig

    problems = []
    solve = lm.local_bundle_adjustment

    def spy(problem, config):
        problems.append((problem, config))
        return solve(problem, config)

    monkeypatch.setattr(lm, "local_bundle_adjustment", spy)
    ds = open_dataset(shared_data / "euroc_V1_01_easy_40frames", sensor="stereo")
    lk2d = FrontendConfig(depth=DepthConfig(stereo_flow="lk2d", stereo_flow_window=11))
    # integer FAST corners: with sub-pixel keypoints (the stereo default since issue 24) this keyframe has no
    # depthless low-parallax point for the filter to leave out (613 points either way)
    system = System(Config(features=FeatureConfig(subpixel="off"), frontend=lk2d, backend=backend,
                           loop=LoopConfig(enabled=False)), ds.camera, "stereo")
    for frame in ds.frames(0, 21):
        system.track(frame)
    system.finish()
    assert len(problems) == 2 and problems[1][0].num_keyframes == 2
    return problems[1]


@pytest.mark.shared
def test_depthless_low_parallax_points_stay_out_of_stereo_ba(shared_data, monkeypatch):
    """EuRoC V1_01 at rest: a far stereo point (> 35 baselines, so monocular in BA) seen from two
    keyframes 1 mm apart has no observable depth. In BA, LM slid it from 4.2 m to the camera centre,
    which moved the free keyframe 0.9 mm, and the default solve stopped half-way: the Schur solver and
    GTSAM (reference) ended 1.0 mm apart. With such points left out (``depthless_min_parallax_deg``)
    both reach the same minimum (measured < 0.01 mm apart)."""
    import dataclasses

    from vslam.backend.bundle_adjustment import local_bundle_adjustment

    def solver_gap(problem, config) -> float:
        a = local_bundle_adjustment(problem, config)
        b = local_bundle_adjustment(problem, dataclasses.replace(config, solver="gtsam"))
        free = ~np.isin(problem.kf_ids, problem.fixed_kf_ids)
        return float(np.max(np.linalg.norm(a.T_world_cam[free, :3, 3] - b.T_world_cam[free, :3, 3], axis=1)))

    kept, kept_cfg = _euroc_second_keyframe_ba(shared_data, monkeypatch, BackendConfig(depthless_min_parallax_deg=0.0))
    left, left_cfg = _euroc_second_keyframe_ba(shared_data, monkeypatch, BackendConfig())
    assert left.num_points < kept.num_points
    assert solver_gap(kept, kept_cfg) > 5e-4  # measured 1.0 mm
    assert solver_gap(left, left_cfg) < 5e-5


@pytest.mark.shared
def test_fr1_desk_local_ba_with_disparity_residual_beats_odometry(shared_data):
    """TUM fr1/desk, 9 frames (3 keyframes), SE(3) ATE: odometry 4.47 mm; local BA with the u_right
    RGB-D residual (the default before issue 5) 4.63 mm, with the disparity residual 4.19 mm (scale 1;
    the default scale sqrt 2: 4.20, re-measured at issue 5 4.39 -> 4.13, u_right 4.4) (all with interpolated
    frames; 4.68 mm before, with rigid frames). The clip's ground truth is noisy at this level (per
    frame-pair RPE 3-8 mm, depth 14 ms after colour), so the margin is small."""
    from vslam.backend.config import LocalBAConfig
    from vslam.datasets import open_dataset

    ds = open_dataset(shared_data / "tum_rgbd_freiburg1_desk_9frames", sensor="rgbd")

    def ate(backend: BackendConfig) -> float:
        system = System(Config(backend=backend, loop=LoopConfig(enabled=False)), ds.camera, "rgbd")
        for frame in ds:
            system.track(frame)
        system.finish()
        traj = system.trajectory()
        assert len(traj) == 9
        return _ate(traj, ds.ground_truth())

    ate_odo = ate(BackendConfig(local_ba=False))
    ate_ba = ate(BackendConfig(local=LocalBAConfig(rgbd_residual="disparity")))  # the default residual
    assert ate_ba < ate_odo - 0.0001, (ate_odo, ate_ba)  # bench: 0.00439 -> 0.00413 (u_right ~0.0044)
    assert ate_ba < 0.0045, ate_ba


def test_max_parallax_deg():
    """Rays from two centres 1 m apart to a point 10 m ahead span atan(0.5/10) * 2 = 5.72 deg; a point
    seen once has none; three rays take the widest from the first."""
    from vslam.backend.local_mapping import max_parallax_deg

    centres = np.array([[-0.5, 0, 0], [0.5, 0, 0], [0, 0, 0], [0, 0, 0], [1.0, 0, 0], [0, 0, 0]], float)
    X = np.array([[0, 0, 10], [0, 0, 10], [0, 0, 5], [3, 0, 4], [3, 0, 4], [3, 0, 4]], float)
    point = np.array([0, 0, 1, 2, 2, 2])
    par = max_parallax_deg(centres, X, point, 3)
    np.testing.assert_allclose(par, [np.degrees(2 * np.arctan(0.05)), 0.0,
                                     np.degrees(np.arccos(np.dot([2, 0, 4], [3, 0, 4]) / (np.sqrt(20) * 5)))], atol=1e-9)
