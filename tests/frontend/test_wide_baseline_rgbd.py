"""Wide-baseline RGB-D tracking on real data: TUM fr3/cabinet, 58 keyframes ~0.67 s apart
(12-20 cm and 3-17 deg between frames, a texture-poor cabinet). The constant-velocity prediction
is useless there; the tracker must fall back to matching without prediction (recent keyframes,
then place recognition) and, with no feature pose at all, to depth ICP, instead of losing track
and starting new map segments (before these fallbacks: 44/58 frames in 8 segments, ATE 0.61 m)."""
from __future__ import annotations

import numpy as np

from vslam.eval.evaluate import evaluate_trajectories


# cabinet_run: the session fixture of tests/conftest.py (shared with the loop and pinned-figure tests)


def test_every_cabinet_frame_is_tracked_in_one_map(cabinet_run):
    ds, system, results = cabinet_run
    stats = system.stats()
    assert len(results) == 58
    assert all(r.T_world_cam is not None for r in results)
    assert stats["frames_lost"] == 0 and stats["map_segments"] == 1
    assert stats["relocalizations"] + system.tracker.n_depth_bridged >= 3  # the fallbacks did the work


def test_cabinet_ate(cabinet_run):
    ds, system, _ = cabinet_run
    res = evaluate_trajectories(system.trajectory(), ds.ground_truth(), max_diff=0.02)
    assert res.matched_poses == 58
    # issue 6: the default pipeline (dense RGB-D refinement, local BA with dense links, the loop
    # closed) under 5 cm; measured 0.032 m (0.166 with no loop closed, 0.134 with the loop before
    # the dense refinement); pinned exactly in tests/test_pinned_figures.py
    assert res.ate.rmse < 0.05, res.ate.rmse
    assert np.isfinite(res.ate_errors).all()
