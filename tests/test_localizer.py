"""Localization in a saved map: cold starts (after the mapped part and in the middle), accuracy
against ground truth, unknown places are not guessed, and the map is never modified."""
from __future__ import annotations

import numpy as np
import pytest

from vslam.api import run_path
from vslam.datasets import open_dataset
from vslam.datasets.frame import Frame
from vslam.datasets.synthetic import SyntheticConfig, render_sequence
from vslam.trajectory import Trajectory
from vslam.localizer import LocalizeResult, Localizer, LocalizerConfig
from vslam.geometry.umeyama import umeyama
from vslam.map.io import load_map

N_FRAMES, N_MAP = 60, 50  # 1.2 laps: frames 50..59 revisit the start of the mapped loop


@pytest.fixture(scope="module")
def mapped(tmp_path_factory):
    """A TUM-layout synthetic RGB-D loop and the map `run_path` built from its first N_MAP frames."""
    root = tmp_path_factory.mktemp("loc")
    cfg = SyntheticConfig(n_frames=N_FRAMES, laps=1.2, width=320, height=240, fx=262.5, fy=262.5, cx=159.5,
                          cy=119.5, stereo=False, pixel_noise=1.0, seed=3)
    seq = root / "seq"
    render_sequence(seq, cfg)
    run = run_path(seq, root / "run", sensor="rgbd", max_frames=N_MAP)
    assert run.stats["tracked"] == N_MAP
    return seq, root / "run"


def _localize(mapped, frames):
    seq, run = mapped
    slam_map, db, _, meta = load_map(run)
    ds = open_dataset(seq, sensor="rgbd")
    loc = Localizer(slam_map, db, ds.camera, sensor=meta["sensor"])
    results = [loc.track(f) for f in frames(ds)]
    return loc, results, ds.ground_truth(), slam_map


def _aligned_errors(results, frames_ts, gt: Trajectory) -> np.ndarray:
    """Position errors of the localized frames after SE(3) alignment of the map frame to the GT frame."""
    ok = [i for i, r in enumerate(results) if r.T_world_cam is not None]
    P = np.stack([results[i].T_world_cam[:3, 3] for i in ok])
    idx = np.searchsorted(gt.timestamps, np.asarray(frames_ts)[ok] - 1e-6)
    Q = gt.positions[idx]
    R, t, _ = umeyama(P, Q, with_scale=False)
    return np.linalg.norm(P @ R.T + t - Q, axis=1)


@pytest.mark.parametrize("start", [N_MAP, 55, 20])
def test_cold_start_localizes_accurately(mapped, start):
    frames_list = []

    def frames(ds):
        for f in ds.frames(start, min(N_FRAMES, start + 10)):
            frames_list.append(f.timestamp)
            yield f

    loc, results, gt, _ = _localize(mapped, frames)
    n = len(results)
    localized = sum(r.T_world_cam is not None for r in results)
    assert n == min(N_FRAMES, start + 10) - start
    assert localized >= 0.9 * n
    assert results[0].state == "localized"  # cold start: global relocalization first
    assert sum(r.state == "tracking" for r in results) >= n // 2  # then tracking against the map
    err = _aligned_errors(results, frames_list, gt)
    assert np.sqrt(np.mean(err ** 2)) < 0.03 and err.max() < 0.05
    s = loc.stats()
    assert s["frames"] == n and s["lost"] == n - localized and s["relocalizations"] >= 1


def test_unknown_place_is_not_localized_and_map_unchanged(mapped):
    seq, run = mapped
    slam_map, db, _, meta = load_map(run)
    before = (slam_map.points.position.copy(), slam_map.points.alive.copy(), len(slam_map.keyframes))
    ds = open_dataset(seq, sensor="rgbd")
    loc = Localizer(slam_map, db, ds.camera, sensor="rgbd")
    rng = np.random.default_rng(0)
    good = list(ds.frames(52, 55))
    noise = Frame(index=999, timestamp=99.0, image=rng.integers(0, 256, (240, 320), dtype=np.uint8),
                  camera=ds.camera, depth=np.ones((240, 320), np.float32))
    blank = Frame(index=998, timestamp=98.0, image=np.full((240, 320), 128, np.uint8), camera=ds.camera,
                  depth=np.zeros((240, 320), np.float32))
    out: list[LocalizeResult] = [loc.track(f) for f in (noise, blank, good[0], good[1], noise, good[2])]
    assert [r.T_world_cam is None for r in out] == [True, True, False, False, True, False]
    assert out[0].state == "lost" and out[2].state == "localized" and out[3].state == "tracking"
    assert out[5].state == "localized"  # after losing track: global relocalization again
    assert loc.stats()["lost"] == 3 and loc.stats()["frames"] == 6
    assert np.array_equal(before[0], slam_map.points.position) and np.array_equal(before[1], slam_map.points.alive)
    assert before[2] == len(slam_map.keyframes)


def test_without_saved_database_and_config_checks(mapped):
    """A map saved without a BoW database: the localizer builds one from the keyframes."""
    seq, run = mapped
    slam_map, _, _, _ = load_map(run)
    ds = open_dataset(seq, sensor="rgbd")
    loc = Localizer(slam_map, None, ds.camera, sensor="rgbd", localize_config=LocalizerConfig(min_inliers=40))
    res = [loc.track(f) for f in ds.frames(50, 53)]
    assert all(r.T_world_cam is not None and r.n_inliers >= 40 for r in res)
    from vslam.errors import ConfigError

    with pytest.raises(ConfigError):
        LocalizerConfig(min_inliers=3)


@pytest.mark.parametrize("mode", ["none", "thread", "process"])
def test_the_run_loop_drives_the_localizer_unchanged(mapped, mode):
    """:func:`run_sequence` drives a Localizer as it drives the SLAM system: the same poses and
    counts as calling ``track`` frame by frame, whatever the prefetch mode; the localized frames'
    trajectory and the localized count come from the localizer."""
    from vslam.datasets.prefetch import FrameRange
    from vslam.runner import run_sequence
    from vslam.stream import FrameResult, FrameTracker

    seq, run = mapped
    ds = open_dataset(seq, sensor="rgbd")

    def localizer():
        slam_map, db, _, _ = load_map(run)
        return Localizer(slam_map, db, ds.camera, sensor="rgbd")

    by_hand = localizer()
    results = [by_hand.track(f) for f in ds.frames(45, 60)]
    assert isinstance(by_hand, FrameTracker) and all(isinstance(r, FrameResult) for r in results)
    res = run_sequence(localizer(), FrameRange(ds, 45, 60), total=15, progress=False, prefetch_mode=mode,
                       prefetch_depth=0 if mode == "none" else 4)
    posed = [r.T_world_cam for r in results if r.T_world_cam is not None]
    assert len(posed) >= 14 and len(res.trajectory) == len(posed)
    np.testing.assert_array_equal(res.trajectory.T_world_cam, np.stack(posed))
    np.testing.assert_array_equal(res.trajectory.timestamps, by_hand.trajectory().timestamps)
    s, h = res.stats, by_hand.stats()
    assert (s["frames"], s["localized"], s["tracked"], s["relocalizations"], s["lost"]) == \
        (15, len(posed), h["tracked"], h["relocalizations"], h["lost"])
    assert s["tracked"] + s["relocalizations"] == s["localized"] and s["prefetch"] == mode
    if mode != "none":  # features of the frames decoded while the localizer was busy were found ahead
        # (process: the 15 frames are all head frames, read and prepared in a thread as the child would start)
        assert s["stage_ms"]["prepare"] > 0.0
    else:
        assert "prepare" not in s["stage_ms"]
