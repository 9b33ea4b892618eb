"""Every sensor x association x motion combination tracks the synthetic loop with a bounded ATE."""
from __future__ import annotations

import pytest

from vslam.errors import ConfigError
from vslam.features.config import FeatureConfig
from vslam.frontend.config import FrontendConfig
from vslam.system import System

from tests.frontend._synthetic import N_FRAMES, ate_rmse, synthetic_frames

# (sensor, association, motion) -> (ATE bound in metres, frames that must have a pose)
CASES = {
    ("rgbd", "match", "3d2d"): (0.01, N_FRAMES),
    ("rgbd", "match", "3d3d"): (0.015, N_FRAMES),
    ("rgbd", "match", "2d2d"): (0.1, N_FRAMES),
    ("rgbd", "track", "3d2d"): (0.01, N_FRAMES),
    ("rgbd", "track", "3d3d"): (0.015, N_FRAMES),
    ("rgbd", "track", "2d2d"): (0.05, N_FRAMES),
    ("stereo", "match", "3d2d"): (0.01, N_FRAMES),
    ("stereo", "match", "3d3d"): (0.04, N_FRAMES),
    ("stereo", "match", "2d2d"): (0.1, N_FRAMES),
    ("stereo", "track", "3d2d"): (0.01, N_FRAMES),
    ("stereo", "track", "3d3d"): (0.035, N_FRAMES),
    ("stereo", "track", "2d2d"): (0.05, N_FRAMES),
    # monocular: Sim(3)-aligned; frames before the two-view initialization are posed afterwards
    ("mono", "match", "3d2d"): (0.08, N_FRAMES - 2),
    ("mono", "match", "2d2d"): (0.08, N_FRAMES - 2),
    ("mono", "track", "3d2d"): (0.04, N_FRAMES - 2),
    ("mono", "track", "2d2d"): (0.3, N_FRAMES - 2),
}


@pytest.mark.parametrize("sensor,association,motion", sorted(CASES))
def test_combination_tracks_synthetic_loop(sensor, association, motion):
    camera, frames, gt = synthetic_frames()
    bound, min_tracked = CASES[(sensor, association, motion)]
    system = System(FrontendConfig(association=association, motion=motion), camera, sensor,
                    features=FeatureConfig(n_features=1000))
    results = [system.track(f) for f in frames]
    system.finish()
    traj = system.trajectory()
    assert len(traj) >= min_tracked
    assert all(r.T_world_cam is None for r in results if r.state != "ok")
    ate = ate_rmse(traj, gt, with_scale=sensor == "mono")
    assert ate < bound, f"{sensor}/{association}/{motion}: ATE {ate:.4f} m >= {bound}"
    stats = system.stats()
    assert stats["keyframes"] >= 2 and stats["loops"] == []
    assert set(stats["stage_ms"]) >= {"features", "association", "pose", "mapping"}
    if motion != "2d2d" or sensor != "mono":
        assert stats["map_points"] > 100


def test_mono_3d3d_is_rejected():
    camera, _, _ = synthetic_frames()
    with pytest.raises(ConfigError):
        System(FrontendConfig(motion="3d3d"), camera, "mono")


def test_bad_option_is_rejected():
    with pytest.raises(ConfigError):
        FrontendConfig(association="optical")
