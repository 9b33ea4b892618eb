"""Parallel local mapping (``backend.mode=parallel``): the local BA solve runs in a worker while
tracking goes on and its result enters the map at a fixed frame lag, so runs are bit-identical."""
from __future__ import annotations

import pytest

from vslam.api import run_path
from vslam.backend.config import BackendConfig
from vslam.errors import ConfigError
from vslam.map.keyframe_queue import LaggedQueue


def _queue(events: list, lag: int) -> LaggedQueue:
    return LaggedQueue(prepare=lambda k: events.append(("prepare", k)) or k,
                       solve=lambda job: job * 10,
                       finish=lambda job, res: events.append(("finish", job, res)),
                       done=lambda k: events.append(("done", k)), lag_frames=lag, name="test")


def test_lagged_queue_finishes_at_the_lag_or_at_the_next_keyframe():
    events: list = []
    q = _queue(events, lag=3)
    q.put(1)
    q.run_pending()  # frame of keyframe 1: prepared, solving
    assert events == [("prepare", 1)]
    q.run_pending()  # +1
    q.run_pending()  # +2
    assert events == [("prepare", 1)]
    q.run_pending()  # +3: the lag is over
    assert events[1:] == [("finish", 1, 10), ("done", 1)]
    q.put(2)
    q.run_pending()
    q.put(3)  # the next keyframe comes before the lag: keyframe 2 is finished first
    q.run_pending()
    assert events[3:] == [("prepare", 2), ("finish", 2, 20), ("done", 2), ("prepare", 3)]
    q.finish()
    assert events[7:] == [("finish", 3, 30), ("done", 3)]


def test_lagged_queue_two_keyframes_in_one_frame_and_no_job():
    events: list = []
    q = LaggedQueue(prepare=lambda k: None if k == 5 else k, solve=lambda j: j, lag_frames=1, name="t",
                    finish=lambda j, r: events.append(("finish", j)), done=lambda k: events.append(("done", k)))
    for k in (4, 5, 6):
        q.put(k)
    q.run_pending()  # 4 solved inline (more waiting), 5 has no problem, 6 goes to the worker
    assert events == [("finish", 4), ("done", 4), ("done", 5)]
    q.finish()
    assert events[3:] == [("finish", 6), ("done", 6)]


def test_backend_mode_and_lag_are_checked():
    with pytest.raises(ConfigError):
        BackendConfig(mode="fast")
    with pytest.raises(ConfigError):
        BackendConfig(mode="parallel", lag_frames=0)
    with pytest.raises(ConfigError):
        BackendConfig(parallel_worker="gpu")


def _run(data, out, sensor, *overrides):
    result = run_path(data, out, sensor=sensor, overrides=["backend.mode=parallel", *overrides], prefetch="none")
    return result.stats, (out / "trajectory.txt").read_bytes()


@pytest.mark.shared
def test_parallel_cabinet_is_bit_identical_run_to_run(shared_data, tmp_path):
    """Two runs in parallel mode (process worker) give the same bytes; a thread worker too; ATE
    measured 0.02833 m (deterministic mode 0.0322), all 58 frames tracked. With integer FAST corners,
    as when measured: with the sub-pixel keypoints of the RGB-D default (issue 24) this row measures
    0.0516 m in parallel mode (deterministic 0.0294; the cabinet's 58 wide-baseline keyframes make
    its ATE jump with any change, benchmarks/RESULTS.md). The depth weight of a registered RGB-D
    sensor (issue 24 round 6) is off here too, as when measured (with it: 0.0359 m)."""
    data = shared_data / "tum_fr3_cabinet_keyframes58"
    as_measured = ("features.subpixel=off", "backend.local.rgbd_disparity_sigma_px=0",
                   "backend.global_ba.rgbd_disparity_sigma_px=0")
    s1, t1 = _run(data, tmp_path / "a", "rgbd", *as_measured)
    s2, t2 = _run(data, tmp_path / "b", "rgbd", *as_measured)
    s3, t3 = _run(data, tmp_path / "c", "rgbd", *as_measured, "backend.parallel_worker=thread")
    assert t1 == t2 == t3
    assert s1["backend"]["mode"] == "parallel" and s1["backend"]["local_ba_calls"] > 40
    assert s1["tracked"] == 58 and s1["lost"] == 0
    assert 0.0283 * 0.985 <= s1["ate_rmse"] <= 0.0283 * 1.015, s1["ate_rmse"]


@pytest.mark.shared
def test_parallel_process_worker_runs_the_visual_inertial_local_ba(shared_data, tmp_path):
    """Stereo-inertial in parallel mode: the child process solves the visual-inertial local BA (the
    job carries the IMU chain; GTSAM's preintegrations pickle) and gives the thread worker's bytes.
    Measured on MH_01 80 frames: 21 VI local BAs and 1 full VI-BA, ATE 0.00296 m (deterministic mode
    0.00288); before, the process worker fell back to the visual local BA."""
    data = shared_data / "euroc_mh01_vi_80"
    s1, t1 = _run(data, tmp_path / "p", "stereo-inertial")
    s2, t2 = _run(data, tmp_path / "t", "stereo-inertial", "backend.parallel_worker=thread")
    assert t1 == t2
    assert s1["backend"]["mode"] == "parallel" and s1["backend"]["vi_ba_calls"] >= 15, s1["backend"]
    assert s1["tracked"] == 80 and s1["ate_rmse"] <= 0.0032, s1["ate_rmse"]  # measured 0.00296 (+8 %)
