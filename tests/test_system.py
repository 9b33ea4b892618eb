"""End-to-end odometry on the real sequences (targets of issue 4) and the System API contract."""
from __future__ import annotations

import numpy as np
import pytest

from vslam.datasets import open_dataset
from vslam.datasets.frame import Frame
from vslam.errors import CalibrationError
from vslam.features.config import FeatureConfig
from vslam.frontend.config import FrontendConfig, TrackingConfig
from vslam.geometry.umeyama import umeyama
from vslam.system import System


def _ate(est, gt, with_scale: bool, tol: float = 0.02) -> tuple[float, int]:
    idx = np.clip(np.searchsorted(gt.timestamps, est.timestamps), 0, len(gt) - 1)
    prev = np.clip(idx - 1, 0, len(gt) - 1)
    idx = np.where(np.abs(gt.timestamps[prev] - est.timestamps) < np.abs(gt.timestamps[idx] - est.timestamps), prev, idx)
    ok = np.abs(gt.timestamps[idx] - est.timestamps) < tol
    P, Q = est.positions[ok], gt.positions[idx[ok]]
    R, t, s = umeyama(P, Q, with_scale=with_scale)
    e = Q - (s * P @ R.T + t)
    return float(np.sqrt((e ** 2).sum(axis=1).mean())), int(ok.sum())


def _run(path, sensor, n_frames=None, frontend=FrontendConfig(), features=FeatureConfig()):
    ds = open_dataset(path, sensor=sensor)
    system = System(frontend, ds.camera, sensor, features=features)
    results = []
    for k, frame in enumerate(ds):
        if n_frames is not None and k >= n_frames:
            break
        results.append(system.track(frame))
    system.finish()
    return ds, system, results


@pytest.mark.shared
def test_tum_fr1_desk_rgbd(shared_data):
    ds, system, results = _run(shared_data / "tum_rgbd_freiburg1_desk_9frames", "rgbd")
    traj = system.trajectory()
    assert len(traj) == 9 and all(r.state == "ok" for r in results)
    ate, n = _ate(traj, ds.ground_truth(), with_scale=False)
    assert n == 9
    assert ate < 0.02


@pytest.mark.shared
def test_kitti06_stereo(shared_data):
    ds, system, results = _run(shared_data / "kitti_odometry" / "sequences" / "06", "stereo")
    traj = system.trajectory()
    assert len(traj) == 51
    ate, n = _ate(traj, ds.ground_truth(), with_scale=False)
    assert n == 51
    assert ate < 0.20


@pytest.mark.shared
def test_kitti07_mono(shared_data):
    ds, system, results = _run(shared_data / "kitti_odometry" / "sequences" / "07", "mono")
    traj = system.trajectory()
    assert len(traj) == 160  # frames before the two-view initialization are posed afterwards
    ate, n = _ate(traj, ds.ground_truth(), with_scale=True)
    assert n == 160
    assert ate < 1.0


@pytest.mark.shared
def test_7scenes_rgbd_subset(shared_data):
    ds, system, results = _run(shared_data / "7scenes_redkitchen", "rgbd", n_frames=300)
    traj = system.trajectory()
    assert len(traj) == 300 and not any(r.state == "lost" for r in results)
    ate, _ = _ate(traj, ds.ground_truth(), with_scale=False)
    assert ate < 0.04
    stats = system.stats()
    assert 3 <= stats["keyframes"] <= 100  # keyframes are chosen, not every frame


def test_system_contract_on_synthetic():
    from tests.frontend._synthetic import synthetic_frames

    camera, frames, gt = synthetic_frames()
    system = System(None, camera, "rgbd", features=FeatureConfig(n_features=800))
    seen_kf = []
    system.add_keyframe_listener(lambda kf: seen_kf.append(kf.id))
    for f in frames[:12]:
        r = system.track(f)
        assert r.frame_index == f.index and r.timestamp == f.timestamp
        assert r.state == "ok" and r.T_world_cam.shape == (4, 4) and r.n_inliers > 50
    assert seen_kf and seen_kf[0] == 0
    system.finish()
    traj = system.trajectory()
    assert len(traj) == 12 and np.all(np.diff(traj.timestamps) > 0)
    kft = system.keyframe_trajectory()
    assert len(kft) == system.stats()["keyframes"] == len(seen_kf)
    # the first pose is the origin, as the map is anchored there
    np.testing.assert_allclose(traj.T_world_cam[0], np.eye(4), atol=1e-12)
    stats = system.stats()
    for key in ("keyframes", "map_points", "loops", "stage_ms"):
        assert key in stats
    # a frame without depth is a user error for an RGB-D system
    bad = Frame(index=99, timestamp=99.0, image=frames[0].image, camera=camera)
    with pytest.raises(Exception, match="no depth"):
        system.track(bad)


def test_system_needs_camera():
    with pytest.raises(CalibrationError):
        System(None, None, "rgbd")


def test_lost_frames_get_no_pose_and_tracking_recovers():
    """A blank frame in the middle is lost (no stale pose); the run goes on afterwards."""
    from tests.frontend._synthetic import synthetic_frames

    camera, frames, gt = synthetic_frames()
    system = System(FrontendConfig(tracking=TrackingConfig(max_lost_frames=2)), camera, "rgbd", features=FeatureConfig(n_features=800))
    states = []
    for k, f in enumerate(frames[:20]):
        if k in (8, 9, 10):
            f = Frame(f.index, f.timestamp, np.zeros_like(f.image), camera, depth=np.zeros_like(f.depth))
        r = system.track(f)
        states.append(r.state)
        if r.state != "ok":
            assert r.T_world_cam is None
    assert states[8] == "lost" and states[9] == "lost"
    assert states[-1] == "ok"
    assert system.stats()["frames_lost"] >= 2
    traj = system.trajectory()
    assert len(traj) == 20 - sum(s != "ok" for s in states)


def test_a_lost_monocular_camera_is_relocalized_for_longer_before_a_new_segment():
    """``tracking.max_lost_frames_mono`` (30): a monocular camera stays *lost* (relocalization tried
    on every frame) for 30 black frames, the 30th starting a new segment that initializes from the
    next frame on, where ``max_lost_frames`` (3) would start it on the 3rd (benchmarks/RESULTS.md,
    round 8)."""
    from tests.frontend._synthetic import synthetic_frames

    camera, frames, _ = synthetic_frames()

    def states(tracking: TrackingConfig) -> list[str]:
        system = System(FrontendConfig(tracking=tracking), camera, "mono")
        out = []
        for k, f in enumerate(frames):
            image = np.zeros_like(f.image) if k >= 8 else f.image
            out.append(system.track(Frame(f.index, f.timestamp, image, camera)).state)
        return out

    default = states(TrackingConfig())
    assert default[:8].count("ok") >= 3  # initialized on the synthetic loop (measured at frame 4)
    assert default[8:38] == ["lost"] * 30 and default[38:] == ["initializing"] * 2
    short = states(TrackingConfig(max_lost_frames_mono=0))  # 0: max_lost_frames
    assert short[8:11] == ["lost"] * 3 and short[11] == "initializing"
