"""Every figure the README publishes, pinned from both sides near its measured value.

The default pipeline is deterministic (bit-identical runs), so each figure sits in a band of
about +-1.5 % around the value measured when it was pinned: an ATE that gets worse *or* better,
a frame that stops being tracked, a loop that closes with other keyframes or another inlier
count, fails here. Re-pin (and update README.md / benchmarks/RESULTS.md) only for a change that
is meant to move them. One run per README "Results" row, as ``vslam bench benchmarks/all.yaml``
runs it (:func:`vslam.api.run_path`, default configuration), plus issue 7's global localization
on 7-Scenes (map of frames 0-599, cold start on 600-999).
"""
from __future__ import annotations

import pytest

from vslam.api import run_path

pytestmark = pytest.mark.shared


def _band(value: float, pinned: float, rel: float = 0.015) -> bool:
    return pinned * (1 - rel) <= value <= pinned * (1 + rel)


# README "Results": run name -> (data folder, sensor, frames, ATE RMSE [m], loops [query, match, inliers])
ROWS = {
    # measured 0.043255; the loop: keyframe 937 -> 248 (frames), 162 inliers
    "7scenes-redkitchen-rgbd": ("7scenes_redkitchen", "rgbd", 1000, 0.04326, [[937, 248, 162]]),
    "tum-fr1-desk-9-rgbd": ("tum_rgbd_freiburg1_desk_9frames", "rgbd", 9, 0.004130, []),  # 0.0041296
    # 0.050001 (0.055783 before stereo matching along the row, frontend.depth.stereo_flow=row, window 9)
    "kitti06-stereo": ("kitti_odometry/sequences/06", "stereo", 51, 0.05000, []),
    "kitti07-mono": ("kitti_odometry/sequences/07", "mono", 160, 0.3263, []),  # 0.326273, scale 9.9283
    # 0.00069020 (0.00086288 before the row stereo matcher: 94 % of keypoints matched instead of 30 %)
    "euroc-v101-40-stereo": ("euroc_V1_01_easy_40frames", "stereo", 40, 0.000690, []),
}


@pytest.fixture(scope="module", params=sorted(ROWS))
def readme_row(request, shared_data, tmp_path_factory):
    name = request.param
    folder, sensor, frames, ate, loops = ROWS[name]
    out = tmp_path_factory.mktemp(name)
    result = run_path(shared_data / folder, out, sensor=sensor, prefetch="none")
    return name, result.stats


def test_readme_row(readme_row):
    name, stats = readme_row
    folder, sensor, frames, ate, loops = ROWS[name]
    # tracked 100 %: every frame has a pose and is matched to the ground truth
    assert stats["frames"] == frames and stats["tracked"] == frames and stats["lost"] == 0, stats
    assert stats["matched_poses"] == frames
    if sensor == "mono":  # Sim(3) alignment: the monocular map's scale, pinned too
        assert _band(stats["scale"], 9.9283, 0.005), stats["scale"]
    else:  # depth sensors are evaluated with SE(3) (no scale absorbs part of the error)
        assert stats["scale"] == 1.0
    assert _band(stats["ate_rmse"], ate), (name, stats["ate_rmse"], ate)
    if loops is not None:
        assert stats["loops"] == loops, (name, stats["loops"])


def test_readme_cabinet_row(cabinet_run):
    """README row tum-fr3-cabinet-kf58-rgbd (the session's cabinet run, tests/conftest.py): all 58
    frames, ATE 0.0322 (measured 0.032233), the circle closed by exactly one loop, keyframe 57 ->
    2 with 10 refined inliers (17 if unrefined RANSAC matches were counted)."""
    from vslam.eval.evaluate import evaluate_trajectories

    ds, system, results = cabinet_run
    assert sum(r.T_world_cam is not None for r in results) == 58
    res = evaluate_trajectories(system.trajectory(), ds.ground_truth())
    assert res.matched_poses == 58
    assert _band(res.ate.rmse, 0.03223), res.ate.rmse
    assert system.stats()["loops"] == [[57, 2, 10]]


@pytest.fixture(scope="module")
def sevenscenes_localization(shared_data, tmp_path_factory):
    """Issue 7: a map of 7-Scenes frames 0-599 (``vslam run --max-frames 600``), then global
    localization from a cold start on frames 600-999 (``vslam localize --start-frame 600``)."""
    from vslam.localize import localize_path

    root = tmp_path_factory.mktemp("7scenes_loc")
    data = shared_data / "7scenes_redkitchen"
    run_path(data, root / "map", sensor="rgbd", max_frames=600, prefetch="none")
    return localize_path(root / "map", data, root / "loc", start_frame=600, max_frames=400).stats


def test_7scenes_localization(sevenscenes_localization):
    """Measured 368/400 localized (354 tracked, 14 relocalized), 32 lost, ATE 0.04946 m. History:
    367/400 (353, 14, 33 lost), 0.04961 before solve_pnp's LM became our own compiled one instead of
    ``cv2.solvePnPRefineLM`` (the same minimum to ~1e-9: the benchmark rows are the same files);
    369/400 (355, 14, 31 lost), 0.04550 before pose refinement stepped with ``lie.so3_exp`` instead of
    ``cv2.Rodrigues`` (the same formula, other rounding: the benchmark rows are the same files, but
    this run moves by two frames and 9 % of ATE: its figures are that sensitive to rounding);
    366/400 (352, 14, 34 lost, 10 implausible steps), 0.04530 before issue 15's per-point Schur sums
    (the map of frames 0-599 moved by 1e-14 m, rounding only, and the counts with it);
    386/400, 0.047 when issue 7 closed; 350/400, 0.0512 after later map changes (the relocalizer's
    RANSAC pose too far off for its guided matching; poses the local map did not confirm were
    reported). Issue 16 asks for >= 360 and < 0.05; the pins below are tighter. Disabling the
    implausible-step check moves every one of these counts."""
    s = sevenscenes_localization
    assert s["frames"] == 400
    assert (s["localized"], s["tracked"], s["relocalizations"], s["lost"]) == (368, 354, 14, 32), s
    assert (s["implausible_steps"], s["track_failures"]) == (9, 13), s
    assert s["localized"] >= 360 and s["ate_rmse"] < 0.05
    assert _band(s["ate_rmse"], 0.04946), s["ate_rmse"]
    assert s["matched_poses"] == s["localized"]
