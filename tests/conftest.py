"""Shared fixtures: where the real sequences are (``VSLAM_SHARED_DATA`` overrides ``../shared/data``)
and the runs several test modules read (each sequence runs once per session)."""
from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def shared_data_dir() -> Path:
    return Path(os.environ.get("VSLAM_SHARED_DATA", REPO.parent / "shared" / "data"))


def shared_data_required() -> bool:
    """In CI (``CI`` set, as GitHub Actions and most runners do) or with
    ``VSLAM_REQUIRE_SHARED_DATA=1`` the real-data tests must run: a missing folder fails them
    instead of skipping them (a green CI that ran none of them proves nothing)."""
    ci = os.environ.get("CI", "").strip().lower() not in ("", "0", "false", "no")
    return ci or os.environ.get("VSLAM_REQUIRE_SHARED_DATA", "").strip() == "1"


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """The real-data folder; tests that use it are skipped when it is absent, except in CI (see
    :func:`shared_data_required`), where they fail."""
    path = shared_data_dir()
    if not path.is_dir():
        msg = f"real sequences not found at {path} (set VSLAM_SHARED_DATA)"
        if shared_data_required():
            pytest.fail(msg + "; CI / VSLAM_REQUIRE_SHARED_DATA=1 needs them", pytrace=False)
        pytest.skip(msg)
    return path


@pytest.fixture
def one_ray_at_a_time(tmp_path_factory):
    """Tests that start a local Ray instance take turns across pytest-xdist's processes (``make
    test`` runs two): a file lock in the run's shared temporary root. Two Ray instances starting at
    once on a loaded 2-core machine can time out waiting for their own GCS servers."""
    from filelock import FileLock

    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):  # each worker has its own basetemp under one root
        root = root.parent
    with FileLock(str(root / "ray.lock")):
        yield


@pytest.fixture(scope="session")
def cabinet_run(shared_data):
    """TUM fr3/cabinet (58 keyframes) through the default pipeline, once per session, with the
    dataset's depth weight as ``vslam run`` resolves it (:func:`vslam.config.with_depth_noise`):
    ``(dataset, system, per-frame results)``."""
    return _cabinet(shared_data, dataset_depth_weight=True)


@pytest.fixture(scope="session")
def cabinet_run_integer_corners(shared_data):
    """The same with integer FAST corners (``features.subpixel=off``, the default before issue 24):
    the run whose weak loop (keyframe 57 -> 2, 10 inliers) tests/loop/test_sparse_loops.py checks;
    with the sub-pixel keypoints of the default that loop is not closed (and the ATE is lower)."""
    return _cabinet(shared_data, ["features.subpixel=off"])


def _cabinet(shared_data, overrides=(), dataset_depth_weight=False):
    from vslam.api import load_config
    from vslam.config import Config, with_depth_noise
    from vslam.datasets import open_dataset
    from vslam.system import System

    ds = open_dataset(shared_data / "tum_fr3_cabinet_keyframes58", sensor="rgbd")
    cfg = load_config(Config, None, list(overrides))
    if dataset_depth_weight:  # else the auto (-1) of a System built directly: the octave weight, as measured before
        cfg = with_depth_noise(cfg, ds.depth_disparity_sigma_px)
    system = System(cfg, ds.camera, sensor="rgbd")
    results = [system.track(f) for f in ds]
    system.finish()
    return ds, system, results


@pytest.fixture(scope="session")
def mh01_stereo_inertial_first50(shared_data: Path, tmp_path_factory) -> Path:
    """A ``vslam run`` folder of EuRoC MH_01's first 50 frames, stereo-inertial (a gravity-aligned
    map), shared by the inertial continue / merge / localize tests: copy it before writing into it."""
    from vslam.api import run_path

    out = tmp_path_factory.mktemp("mh01_vi_first50") / "A"
    run_path(shared_data / "euroc_mh01_vi_80", out, sensor="stereo-inertial", max_frames=50, prefetch="none")
    return out
