"""Saved maps keep the inertial state: gravity alignment, per-keyframe velocity and biases, and the
IMU metadata (FORMAT.md, "Visual-inertial maps"); older and visual maps load as before."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from vslam.errors import MapFormatError
from vslam.inertial import ImuCalibration
from vslam.map.io import load_map, save_map
from vslam.map.io_inertial import inertial_metadata
from tests.map._builders import assert_maps_equal, random_map, rewrite_npz


def inertial_map(seed: int = 3):
    m = random_map(seed, n_keyframes=6, n_keypoints=50)
    rng = np.random.default_rng(seed)
    m.gravity_aligned = True
    for kf in m.keyframes.values():
        # values that JSON text could not carry exactly (full-precision doubles, a subnormal)
        kf.extra["imu_velocity"] = rng.normal(size=3) * np.pi
        kf.extra["imu_bias"] = np.concatenate([rng.normal(size=3) * 1e-3, rng.normal(size=3) * 1e-1])
    next(iter(m.keyframes.values())).extra["imu_bias"][0] = 5e-324
    return m


def calibration() -> ImuCalibration:
    T = np.eye(4)
    T[:3, 3] = [0.02, -0.07, 0.01]
    return ImuCalibration(T, source="sensor.yaml (cam0, imu0)")


def test_inertial_state_round_trips_exactly(tmp_path: Path) -> None:
    m = inertial_map()
    meta = {"sensor": "stereo-inertial", "inertial": inertial_metadata(calibration())}
    save_map(m, tmp_path, metadata=meta)
    manifest = json.loads((tmp_path / "map/map.json").read_text())
    assert manifest["map_attributes"]["gravity_aligned"] is True
    back, _, _, meta_back = load_map(tmp_path)
    assert back.gravity_aligned is True
    assert_maps_equal(m, back)  # every extra array bit-exact, dtype and shape included
    for k, kf in m.keyframes.items():
        for key in ("imu_velocity", "imu_bias"):
            b = back.keyframes[k].extra[key]
            assert b.dtype == np.float64 and b.tobytes() == kf.extra[key].tobytes()
    assert meta_back == meta
    assert meta_back["inertial"]["gravity_m_s2"] == pytest.approx(9.81, abs=0.01)
    assert back.segment_gravity_aligned(0)


def test_visual_and_older_maps_load_unaligned(tmp_path: Path) -> None:
    m = random_map(4, n_keyframes=3, n_keypoints=30)
    save_map(m, tmp_path)
    back, *_ = load_map(tmp_path)
    assert back.gravity_aligned is False and not back.segment_gravity_aligned(0)
    # a map written before the attribute existed (no map_attributes.gravity_aligned) loads unaligned
    path = tmp_path / "map/map.json"
    manifest = json.loads(path.read_text())
    del manifest["map_attributes"]["gravity_aligned"]
    path.write_text(json.dumps(manifest))
    back, *_ = load_map(tmp_path)
    assert back.gravity_aligned is False
    manifest["map_attributes"]["gravity_aligned"] = 1
    path.write_text(json.dumps(manifest))
    with pytest.raises(MapFormatError, match="gravity_aligned must be true or false"):
        load_map(tmp_path)


def test_loader_refuses_a_corrupted_inertial_state(tmp_path: Path) -> None:
    m = inertial_map()
    save_map(m, tmp_path)
    root = tmp_path / "map"
    manifest = json.loads((root / "map.json").read_text())
    arrays = manifest["files"]["keyframes.npz"]["arrays"]
    member = next(k for k, v in arrays.items() if k.startswith("extra.") and v["shape"] == [3])

    def nan_velocity(a):
        a[member] = a[member].copy()
        a[member][1] = np.nan
        return a

    rewrite_npz(root, "keyframes.npz", nan_velocity)
    with pytest.raises(MapFormatError, match=r"extra\['imu_velocity'\] must be finite float64\[3\]"):
        load_map(tmp_path)

    save_map(m, tmp_path)
    rewrite_npz(root, "keyframes.npz", lambda a: {**a, member: a[member][:2]}, update_spec=True)
    with pytest.raises(MapFormatError, match=r"imu_velocity.*got float64\[2\]"):
        load_map(tmp_path)


def test_inertial_metadata_is_checked(tmp_path: Path) -> None:
    m = inertial_map()
    bad = inertial_metadata(calibration())
    bad["gravity_m_s2"] = 1.0  # g in units of g, not m/s^2
    with pytest.raises(MapFormatError, match="not a gravity magnitude"):
        save_map(m, tmp_path, metadata={"inertial": bad})
    with pytest.raises(MapFormatError, match="must hold exactly"):
        save_map(m, tmp_path, metadata={"inertial": {"gravity_m_s2": 9.81}})
    good = inertial_metadata(calibration())
    save_map(m, tmp_path, metadata={"inertial": good})
    path = tmp_path / "map/map.json"
    manifest = json.loads(path.read_text())
    manifest["metadata"]["inertial"]["T_imu_cam"][0][0] = 2.0
    path.write_text(json.dumps(manifest))
    with pytest.raises(MapFormatError, match="T_imu_cam must be a finite rigid"):
        load_map(tmp_path)
