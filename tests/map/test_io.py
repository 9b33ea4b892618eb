"""Map save/load: exact round trips, atomic writes, precise errors on damaged maps, speed."""
from __future__ import annotations

import dataclasses
import json
import logging
import shutil
import time
from pathlib import Path

import numpy as np
import pytest

import vslam.map.io as mio
import vslam.map.io_pack as io_pack
import vslam.map.io_unpack as io_unpack
from vslam.errors import MapFormatError
from vslam.geometry.camera import PinholeCamera
from vslam.map.io import load_map, save_map
from vslam.map.keyframe import KeyFrame
from vslam.map.map import Map
from vslam.map.mappoint import MapPointStore
from tests.map._builders import (assert_maps_equal, large_map, random_database, random_map,
                                 rewrite_npz)

CAMERA = PinholeCamera(585.0, 585.5, 320.25, 240.75, 640, 480, (0.1, -0.2, 0.001, 0.002, 0.03), 0.075)
FORMAT_MD = Path(mio.__file__).with_name("FORMAT.md")


@pytest.fixture(scope="module")
def orb_map() -> Map:
    return random_map(1, mode="orb")


@pytest.fixture()
def saved(tmp_path: Path, orb_map: Map) -> Path:
    return save_map(orb_map, tmp_path, database=random_database(2, list(orb_map.keyframes)), camera=CAMERA,
                    metadata={"sequence": "office", "frames": 1000})


def _error(root: Path) -> str:
    with pytest.raises(MapFormatError) as info:
        load_map(root.parent)
    return str(info.value)


# ----------------------------------------------------------------------------- round trips
@pytest.mark.parametrize("mode", ["orb", "klt", "mixed"])
def test_round_trip_is_exact(tmp_path: Path, mode: str) -> None:
    m = random_map(7, mode=mode)
    assert len(m.keyframes) == 10 and m.points.n_alive > 300 and sum(map(len, m.covisibility.values())) > 20
    if mode == "klt":
        assert m.points.descriptor is None and all(kf.descriptors is None for kf in m.keyframes.values())
    if mode == "mixed":
        assert {kf.descriptors is None for kf in m.keyframes.values()} == {True, False}
    db = random_database(3, list(m.keyframes))
    meta = {"sequence": "fr1/desk", "ate": [0.031, None], "nested": {"ok": True}}
    path = save_map(m, tmp_path, database=db, camera=CAMERA, metadata=meta)
    assert path == tmp_path / "map"
    assert sorted(p.name for p in path.iterdir()) == ["covisibility.npz", "database.npz", "keyframes.npz",
                                                      "map.json", "points.npz"]
    m2, db2, cam2, meta2 = load_map(tmp_path)
    assert_maps_equal(m, m2)
    assert cam2 == CAMERA and meta2 == meta
    assert db2.keyframe_ids == db.keyframe_ids and db2.n_words == db.n_words
    for k in db.keyframe_ids:
        assert np.array_equal(db.bow(k).words, db2.bow(k).words) and np.array_equal(db.bow(k).values, db2.bow(k).values)
    q = db.bow(db.keyframe_ids[-1])
    assert db.query(q, 5) == db2.query(q, 5)
    # the loaded map behaves like the original
    kf_id = list(m.keyframes)[-1]
    assert m2.local_keyframes(kf_id, 3) == m.local_keyframes(kf_id, 3)
    assert np.array_equal(m2.local_point_ids([kf_id]), m.local_point_ids([kf_id]))
    assert m2.next_keyframe_id() == m.next_keyframe_id() == 10
    new_ids = m2.points.add(np.zeros((5, 3)), None if m2.points.descriptor is None else np.zeros((5, 32), np.uint8),
                            np.ones(3), kf_id)
    assert new_ids.tolist() == list(range(len(m.points), len(m.points) + 5))


def test_keyframe_poses_alone_are_the_loaded_maps(tmp_path: Path) -> None:
    """``load_keyframe_poses`` (``vslam map``'s finalize) reads only ``keyframes.npz``: the same
    good keyframes and poses as a whole load, bit for bit (no arithmetic in between)."""
    m = random_map(7, mode="orb")
    bad = sorted(m.keyframes)[3]
    m.keyframes[bad].bad = True
    save_map(m, tmp_path, camera=CAMERA)
    poses = mio.load_keyframe_poses(tmp_path)
    assert sorted(poses) == sorted(k for k, kf in m.keyframes.items() if not kf.bad) and bad not in poses
    for k, T in poses.items():
        assert np.array_equal(T, m.keyframes[k].T_world_cam)
    with open(tmp_path / "map" / "keyframes.npz", "r+b") as fh:  # a flipped byte: refused, as by load_map
        fh.seek(200)
        b = fh.read(1)
        fh.seek(200)
        fh.write(bytes([b[0] ^ 0xFF]))
    with pytest.raises(MapFormatError, match="checksum mismatch"):
        mio.load_keyframe_poses(tmp_path)


def test_resave_is_byte_identical(tmp_path: Path, orb_map: Map) -> None:
    save_map(orb_map, tmp_path / "a", camera=CAMERA)
    m2, _, cam, _ = load_map(tmp_path / "a")
    save_map(m2, tmp_path / "b", camera=cam)
    for name in ("keyframes.npz", "points.npz", "covisibility.npz"):
        assert (tmp_path / "a/map" / name).read_bytes() == (tmp_path / "b/map" / name).read_bytes(), name


def test_empty_map_and_defaults(tmp_path: Path) -> None:
    save_map(Map(), tmp_path)
    m, db, cam, meta = load_map(tmp_path / "map")  # the map folder itself is accepted too
    assert_maps_equal(Map(), m)
    assert db is None and cam is None and meta == {}


def test_manifest_documents_the_files(saved: Path, orb_map: Map) -> None:
    manifest = json.loads((saved / "map.json").read_text())
    assert manifest["format"] == "vslam-map" and manifest["version"] == 2 and manifest["segments"] == []
    assert manifest["counts"]["keyframes"] == 10
    assert manifest["counts"]["keypoints"] == sum(len(kf.uv) for kf in orb_map.keyframes.values())
    assert manifest["counts"]["point_rows"] == len(orb_map.points)
    assert manifest["keyframe_fields"] == mio.KEYFRAME_FIELD_KINDS
    kf_arrays = manifest["files"]["keyframes.npz"]["arrays"]
    assert kf_arrays["T_world_cam"] == {"dtype": "<f8", "shape": [10, 4, 4]}
    assert kf_arrays["descriptors"]["dtype"] == "|u1"
    assert manifest["files"]["covisibility.npz"]["arrays"]["edges"]["shape"][1] == 3
    assert all(len(f["sha256"]) == 64 for f in manifest["files"].values())
    for name in ("keyframes.npz", "points.npz", "covisibility.npz"):  # plain npz, no pickled objects
        with np.load(saved / name, allow_pickle=False) as z:
            assert all(z[k].dtype != object for k in z.files)


# ----------------------------------------------------------------------------- format stays honest
def test_format_covers_every_field() -> None:
    """Fails when KeyFrame / MapPointStore / Map gain a field that map format 1 does not document:
    then add it to KEYFRAME_FIELD_KINDS / POINT_COLUMNS and FORMAT.md (and bump the version if old
    maps cannot be read any more)."""
    kf_fields = [f.name for f in dataclasses.fields(KeyFrame)]
    assert set(kf_fields) == set(mio.KEYFRAME_FIELD_KINDS), "KeyFrame fields changed: update vslam/map/io_format.py"
    store = MapPointStore()
    columns = [k for k, v in vars(store).items() if isinstance(v, np.ndarray) or v is None]
    assert set(columns) == set(mio.POINT_COLUMNS), "MapPointStore columns changed: update vslam/map/io_format.py"
    others = [k for k in vars(store) if k not in columns]
    assert set(others) == {"_n", "_cap"}
    # loop_epoch: a runtime counter (realtime stale-result check), deliberately not saved
    assert set(vars(Map())) == set(mio.MAP_STRUCTURES) | {"_next_kf_id", "loop_epoch"}, "Map attributes changed"
    doc = FORMAT_MD.read_text()
    for name in kf_fields + columns + ["_next_kf_id", "loop_epoch", "_n", "_cap", "n_keypoints", "nodes", "edges"]:
        assert f"`{name}`" in doc, f"FORMAT.md does not document {name}"


def test_unknown_keyframe_field_is_saved_generically(tmp_path: Path, monkeypatch, caplog) -> None:
    """A field the format does not document yet is saved by inferred kind (with a warning) and loads back."""

    @dataclasses.dataclass
    class KeyFrameV2(KeyFrame):
        quality: float = 0.0
        descriptor_mask: np.ndarray | None = None
        intrinsics_scale: np.ndarray | None = None

    m = random_map(5, n_keyframes=4, n_keypoints=40)
    m2 = Map()
    for kf in m.keyframes.values():
        d = {f.name: getattr(kf, f.name) for f in dataclasses.fields(KeyFrame)}
        n = len(kf.uv)
        v2 = KeyFrameV2(**d, quality=0.25 * kf.id, descriptor_mask=np.arange(n) % 3 == 0,
                        intrinsics_scale=np.full((2, 2), kf.id, np.float32))
        m2.keyframes[kf.id] = v2
    m2.points, m2.covisibility, m2._next_kf_id = m.points, m.covisibility, m._next_kf_id
    monkeypatch.setattr(io_pack, "KeyFrame", KeyFrameV2)
    monkeypatch.setattr(io_unpack, "KeyFrame", KeyFrameV2)
    with caplog.at_level(logging.WARNING, logger="vslam.map.io_pack"):
        save_map(m2, tmp_path)
    assert "quality" in caplog.text and "intrinsics_scale" in caplog.text
    layout = json.loads((tmp_path / "map/map.json").read_text())["keyframe_fields"]
    assert (layout["quality"], layout["descriptor_mask"], layout["intrinsics_scale"]) == ("scalar", "keypoint", "stacked")
    back, *_ = load_map(tmp_path)
    assert_maps_equal(m2, back)
    # a build whose KeyFrame lacks the new fields refuses the map instead of dropping them
    monkeypatch.setattr(io_unpack, "KeyFrame", KeyFrame)
    with pytest.raises(MapFormatError, match=r"keyframe fields \['quality', 'descriptor_mask', 'intrinsics_scale'\] "
                                             r"are unknown to this build"):
        load_map(tmp_path)


def test_values_that_cannot_be_saved_exactly_are_refused(tmp_path: Path) -> None:
    m = random_map(4, n_keyframes=3, n_keypoints=30)
    with pytest.raises(MapFormatError, match="metadata: not JSON-serializable"):
        save_map(m, tmp_path, metadata={"x": object()})
    with pytest.raises(MapFormatError, match="metadata: it would not load back equal"):
        save_map(m, tmp_path, metadata={"x": (1, 2)})
    m.keyframes[1].octave = m.keyframes[1].octave.astype(np.int64)
    with pytest.raises(MapFormatError, match=r"KeyFrame.octave exactly: keyframes hold int32\[\d+\] and int64"):
        save_map(m, tmp_path)
    m.keyframes[1].octave = m.keyframes[1].octave[:-1].astype(np.int32)
    with pytest.raises(MapFormatError, match=r"KeyFrame.octave: keyframe 1 has \(\d+,\) values for its \d+ keypoints"):
        save_map(m, tmp_path)
    assert not (tmp_path / "map").exists() and not list(tmp_path.iterdir())  # no temp folders left


# ----------------------------------------------------------------------------- atomic writes
def test_save_replaces_an_existing_map_atomically(tmp_path: Path, monkeypatch) -> None:
    first, second = random_map(1, n_keyframes=3, n_keypoints=50), random_map(2, n_keyframes=5, n_keypoints=50)
    save_map(first, tmp_path, metadata={"run": 1})
    save_map(second, tmp_path, metadata={"run": 2})
    m, _, _, meta = load_map(tmp_path)
    assert meta == {"run": 2} and len(m.keyframes) == 5
    assert sorted(p.name for p in tmp_path.iterdir()) == ["map"]

    def crash(*args, **kwargs):
        raise KeyboardInterrupt("power cut")

    monkeypatch.setattr(mio.np, "savez", crash)  # dies half-way through writing the arrays
    with pytest.raises(KeyboardInterrupt):
        save_map(first, tmp_path, metadata={"run": 3})
    monkeypatch.undo()
    m, _, _, meta = load_map(tmp_path)
    assert meta == {"run": 2} and len(m.keyframes) == 5
    assert sorted(p.name for p in tmp_path.iterdir()) == ["map"]


def test_interrupted_first_save_leaves_no_map(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setattr(mio, "_fsync_dir", lambda path: (_ for _ in ()).throw(OSError("disk full")))
    with pytest.raises(OSError):
        save_map(random_map(1, n_keyframes=2, n_keypoints=20), tmp_path)
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(MapFormatError, match=r"map\.json is missing"):
        load_map(tmp_path)


# ----------------------------------------------------------------------------- damaged maps
def test_missing_manifest(saved: Path) -> None:
    (saved / "map.json").unlink()
    msg = _error(saved)
    assert f"{saved / 'map.json'} is missing" in msg


def test_missing_directory(tmp_path: Path) -> None:
    with pytest.raises(MapFormatError, match="does not exist"):
        load_map(tmp_path / "nowhere")


def test_truncated_manifest(saved: Path) -> None:
    text = (saved / "map.json").read_text()
    (saved / "map.json").write_text(text[: len(text) // 2])
    assert "map.json is unreadable or not valid JSON" in _error(saved)


def test_wrong_version(saved: Path) -> None:
    manifest = json.loads((saved / "map.json").read_text())
    manifest["version"] = 3
    (saved / "map.json").write_text(json.dumps(manifest))
    assert _error(saved) == f"{saved / 'map.json'}: unsupported version 3 (this build reads versions 1 and 2)"


def test_wrong_format_name(saved: Path) -> None:
    manifest = json.loads((saved / "map.json").read_text())
    manifest["format"] = "orbslam-atlas"
    (saved / "map.json").write_text(json.dumps(manifest))
    assert "format 'orbslam-atlas' is not 'vslam-map'" in _error(saved)


@pytest.mark.parametrize("name", ["keyframes.npz", "points.npz", "covisibility.npz", "database.npz"])
def test_truncated_file(saved: Path, name: str) -> None:
    data = (saved / name).read_bytes()
    (saved / name).write_bytes(data[: len(data) // 2])
    assert _error(saved) == (f"{saved / name} is truncated: {len(data) // 2} bytes, map.json says {len(data)}")


@pytest.mark.parametrize("name", ["keyframes.npz", "points.npz", "covisibility.npz", "database.npz"])
def test_missing_file(saved: Path, name: str) -> None:
    (saved / name).unlink()
    assert _error(saved) == f"{saved / name} is missing (listed in map.json)"


@pytest.mark.parametrize("name", ["keyframes.npz", "points.npz"])
def test_flipped_bytes(saved: Path, name: str) -> None:
    data = bytearray((saved / name).read_bytes())
    data[len(data) // 2] ^= 0xFF
    data[len(data) // 3] ^= 0x01
    (saved / name).write_bytes(bytes(data))
    assert _error(saved) == f"{saved / name}: checksum mismatch (SHA-256 differs from map.json): the file is corrupted"
    # without the checksum the zip CRC still catches it: an error, never a silently wrong map
    with pytest.raises(MapFormatError, match=f"{name} is unreadable"):
        load_map(saved, verify_checksums=False)


def test_missing_array(saved: Path) -> None:
    rewrite_npz(saved, "keyframes.npz", lambda a: {k: v for k, v in a.items() if k != "depth"})
    assert _error(saved) == f"{saved / 'keyframes.npz'}: missing array 'depth'"


def test_missing_array_not_listed(saved: Path) -> None:
    rewrite_npz(saved, "points.npz", lambda a: {k: v for k, v in a.items() if k != "normal"}, update_spec=True)
    msg = _error(saved)
    assert msg == f"{saved / 'points.npz'}: missing array 'normal'"


def test_array_differs_from_manifest(saved: Path) -> None:
    rewrite_npz(saved, "keyframes.npz", lambda a: {**a, "T_world_cam": a["T_world_cam"][:, :3]})
    assert _error(saved) == (f"{saved / 'keyframes.npz'}: array 'T_world_cam' is <f8[10, 3, 4], "
                             "map.json says <f8[10, 4, 4]")


def test_wrong_shape(saved: Path) -> None:
    rewrite_npz(saved, "keyframes.npz", lambda a: {**a, "T_world_cam": a["T_world_cam"][:, :3]}, update_spec=True)
    assert _error(saved) == (f"{saved / 'keyframes.npz'}: array 'T_world_cam' has the wrong shape (10, 3, 4), "
                             "expected (*, 4, 4)")


def test_wrong_row_count(saved: Path) -> None:
    rewrite_npz(saved, "points.npz", lambda a: {**a, "position": a["position"][:-1]}, update_spec=True)
    n = json.loads((saved / "map.json").read_text())["point_store"]["rows"]
    assert _error(saved) == (f"{saved / 'points.npz'}: array 'position' has the wrong shape ({n - 1}, 3), "
                             f"expected ({n}, ...)")


def test_point_ids_out_of_range(saved: Path) -> None:
    def bump(a):
        ids = a["point_ids"].copy()
        ids[0] = 10**6
        return {**a, "point_ids": ids}

    rewrite_npz(saved, "keyframes.npz", bump)
    assert "point_ids reference point 1000000" in _error(saved)


def test_pickled_array_is_refused(saved: Path) -> None:
    rewrite_npz(saved, "keyframes.npz", lambda a: {**a, "extra": np.array([{}] * 10, dtype=object)}, update_spec=True)
    msg = _error(saved)
    assert "keyframes.npz" in msg and "holds Python objects" in msg  # refused before np.load would unpickle


def test_random_damage_never_crashes(tmp_path: Path) -> None:
    """Seeded fuzz: flipped, cut or inserted bytes in any file give a MapFormatError (checksums on),
    and with checksums off either an error or, when only zip metadata was hit, the exact map."""
    m = random_map(3, n_keyframes=4, n_keypoints=60, mode="mixed")
    save_map(m, tmp_path / "base", database=random_database(1, list(m.keyframes)))
    rng = np.random.default_rng(0)
    names = ["keyframes.npz", "points.npz", "covisibility.npz", "database.npz", "map.json"]
    outcomes = {"error": 0, "equal": 0}
    for it in range(60):
        root = tmp_path / f"case{it}" / "map"
        shutil.copytree(tmp_path / "base" / "map", root)
        name = names[it % len(names)]
        data = bytearray((root / name).read_bytes())
        pos = int(rng.integers(len(data)))
        op = it // len(names) % 3
        if op == 0:
            data[pos] ^= int(rng.integers(1, 256))
        elif op == 1:
            data = data[:pos]
        else:
            data[pos:pos] = b"\x00"
        (root / name).write_bytes(bytes(data))
        for verify in (True, False):
            try:
                m2, *_ = load_map(root, verify_checksums=verify)
            except MapFormatError:
                outcomes["error"] += 1
                continue
            assert name == "map.json" or not verify, f"case {it}: damaged {name} loaded despite the checksum"
            assert_maps_equal(m, m2)
            outcomes["equal"] += 1
    assert outcomes["error"] > 100


# ----------------------------------------------------------------------------- real frontend maps
@pytest.mark.parametrize("sensor,association", [("rgbd", "match"), ("mono", "track")])
def test_frontend_map_round_trip(tmp_path: Path, sensor: str, association: str) -> None:
    """A map made by the real tracker on the synthetic loop (ORB descriptors / KLT without) reloads exactly."""
    from vslam.features.config import FeatureConfig
    from vslam.frontend.config import FrontendConfig
    from vslam.system import System
    from tests.frontend._synthetic import synthetic_frames

    camera, frames, _ = synthetic_frames()
    system = System(FrontendConfig(association=association), camera, sensor, features=FeatureConfig(n_features=500))
    for frame in frames[:12]:
        system.track(frame)
    m = system.map
    assert len(m.keyframes) >= 2 and m.n_points > 100
    assert (m.points.descriptor is None) == (association == "track")
    save_map(m, tmp_path, camera=camera)
    m2, _, cam2, _ = load_map(tmp_path)
    assert cam2 == camera
    assert_maps_equal(m, m2)


# ----------------------------------------------------------------------------- speed
def test_large_map_speed(tmp_path: Path) -> None:
    """150 keyframes x 1500 ORB keypoints, 60000 points (a 1000-frame 7-Scenes RGB-D run)."""
    m = large_map()
    t0 = time.perf_counter()
    path = save_map(m, tmp_path, camera=CAMERA)
    t_save = time.perf_counter() - t0
    t0 = time.perf_counter()
    m2, _, _, _ = load_map(tmp_path)
    t_load = time.perf_counter() - t0
    size_mb = sum(p.stat().st_size for p in path.iterdir()) / 1e6
    logging.getLogger(__name__).info("large map: save %.2f s, load %.2f s, %.1f MB", t_save, t_load, size_mb)
    print(f"\nlarge map: save {t_save:.3f} s, load {t_load:.3f} s, {size_mb:.1f} MB")
    assert len(m2.keyframes) == 150 and len(m2.points) == 60000
    assert_maps_equal(m, m2)
    assert t_save < 6.0 and t_load < 6.0
