"""Random maps built through the Map API the way the frontend builds them, and exact comparisons.

The frontend (``vslam/frontend/tracker.py``) makes a KeyFrame with ``point_ids = -1`` plus the ids of
the points it tracked, creates new points with ``map.points.add`` (from depth or triangulation),
writes their ids into ``kf.point_ids``, then calls ``map.add_keyframe`` (covisibility), counts
visibility with ``points.record`` and culls/compacts the store.
"""
from __future__ import annotations

import dataclasses
import json
import hashlib
from pathlib import Path

import numpy as np

from vslam.map.database import KeyframeDatabase
from vslam.loop.vocabulary import BowVector
from vslam.map.keyframe import KeyFrame
from vslam.map.map import Map
from vslam.map.mappoint import MapPointStore

SCALE_FACTOR = 1.2
N_LEVELS = 8


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    q = rng.normal(size=4)
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def random_map(seed: int, n_keyframes: int = 10, n_keypoints: int = 300, mode: str = "orb") -> Map:
    """A map grown keyframe by keyframe.

    ``mode``: ``"orb"`` (descriptors everywhere, RGB-D virtual right u), ``"klt"`` (no descriptors,
    no u_right: the store has no descriptor column), ``"mixed"`` (some keyframes without
    descriptors/u_right, some ``extra`` entries, a bad keyframe).
    """
    rng = np.random.default_rng(seed)
    m = Map()
    max_level_scale = SCALE_FACTOR ** (N_LEVELS - 1)
    for k in range(n_keyframes):
        T_world_cam = np.eye(4)
        T_world_cam[:3, :3] = random_rotation(rng)
        T_world_cam[:3, 3] = rng.normal(size=3)
        n = int(n_keypoints + rng.integers(-30, 30))
        uv = rng.uniform(0, 640, (n, 2))
        has_desc = mode == "orb" or (mode == "mixed" and k % 3 != 1)
        descriptors = rng.integers(0, 256, (n, 32), dtype=np.uint8) if has_desc else None
        octave = rng.integers(0, N_LEVELS, n).astype(np.int32)  # Features.octave is int32
        depth = rng.uniform(0.3, 6.0, n)
        depth[rng.random(n) < 0.2] = np.nan
        has_right = mode == "orb" or (mode == "mixed" and k % 2 == 0)
        kf = KeyFrame(
            id=m.next_keyframe_id(), frame_index=3 * k + int(rng.integers(0, 3)), timestamp=1.3e9 + 0.0333 * k + rng.random() * 1e-3,
            T_world_cam=T_world_cam, uv=uv, uv_undist=uv + rng.normal(scale=0.5, size=(n, 2)),
            descriptors=descriptors, octave=octave, depth=depth, point_ids=np.full(n, -1, dtype=np.int64),
            segment=k // 4, u_right=(uv[:, 0] - 40.0 / depth) if has_right else None,
        )
        if mode == "mixed" and k == 2:
            kf.extra = {"note": "relocalized", "scores": [0.5, float("nan")], "mask": rng.random(n) < 0.5,
                        "nested": {"a": [1, 2], "b": None}}
        # track some alive points of earlier keyframes
        alive = np.flatnonzero(m.points.alive[: len(m.points)])
        if len(alive):
            seen = rng.choice(alive, size=min(len(alive), n // 3), replace=False)
            slots = rng.choice(n, size=len(seen), replace=False)
            kf.point_ids[slots] = seen
            m.points.record(seen, seen[rng.random(len(seen)) < 0.7])
        # new points from depth (tracker._points_from_depth)
        cand = np.flatnonzero((kf.point_ids < 0) & np.isfinite(kf.depth))[: n // 3]
        Xw = rng.normal(size=(len(cand), 3)) * 2.0 + T_world_cam[:3, 3]
        desc = None if kf.descriptors is None else kf.descriptors[cand]
        ids = m.points.add(Xw, desc, T_world_cam[:3, 3], kf.id,
                           np.power(SCALE_FACTOR, kf.octave[cand].astype(float)), max_level_scale)
        kf.point_ids[cand] = ids
        m.add_keyframe(kf)
        if k == n_keyframes // 2:
            m.cull_points(0.6, min_visible=2)
            m.compact()
    if mode == "mixed":
        m.keyframes[1].bad = True
        # a non-sorted graph order (Map.covisible breaks weight ties by it): must survive the round trip
        m.covisibility = {i: dict(reversed(list(links.items()))) for i, links in reversed(list(m.covisibility.items()))}
    return m


def random_database(seed: int, keyframe_ids: list[int], n_words: int = 1000) -> KeyframeDatabase:
    rng = np.random.default_rng(seed)
    db = KeyframeDatabase(n_words)
    for kf_id in keyframe_ids:
        words = np.unique(rng.choice(n_words, 80)).astype(np.int32)
        values = rng.random(words.size)
        db.add(kf_id, BowVector(words, values / values.sum()))
    return db


def large_map(seed: int = 0, n_keyframes: int = 150, n_keypoints: int = 1500, n_points: int = 60000,
              n_covisible: int = 30) -> Map:
    """A map the size of a 1000-frame 7-Scenes RGB-D run, filled directly (fast, no covisibility
    search): ``n_keyframes`` x ``n_keypoints`` ORB keypoints, ``n_points`` points, each keyframe
    linked to its ``n_covisible`` neighbours."""
    rng = np.random.default_rng(seed)
    m = Map()
    m.points = MapPointStore()
    per_kf = n_points // n_keyframes
    for k in range(n_keyframes):
        T_world_cam = np.eye(4)
        T_world_cam[:3, :3] = random_rotation(rng)
        T_world_cam[:3, 3] = rng.normal(size=3)
        uv = rng.uniform(0, 640, (n_keypoints, 2))
        depth = rng.uniform(0.3, 6.0, n_keypoints)
        kf = KeyFrame(
            id=k, frame_index=7 * k, timestamp=float(k) / 30.0, T_world_cam=T_world_cam, uv=uv, uv_undist=uv + 0.1,
            descriptors=rng.integers(0, 256, (n_keypoints, 32), dtype=np.uint8),
            octave=rng.integers(0, N_LEVELS, n_keypoints).astype(np.int32), depth=depth,
            point_ids=np.full(n_keypoints, -1, dtype=np.int64), u_right=uv[:, 0] - 40.0 / depth,
        )
        ids = m.points.add(rng.normal(size=(per_kf, 3)), kf.descriptors[:per_kf], T_world_cam[:3, 3], k)
        kf.point_ids[:per_kf] = ids
        if len(m.points) > 2 * per_kf:
            kf.point_ids[per_kf: 2 * per_kf] = rng.choice(len(m.points) - per_kf, per_kf, replace=False)
        m.keyframes[k] = kf
        m._next_kf_id = k + 1
        m.covisibility[k] = {}
        for j in range(max(0, k - n_covisible), k):
            w = int(rng.integers(15, 400))
            m.covisibility[k][j] = w
            m.covisibility[j][k] = w
    return m


# ----------------------------------------------------------------------------- comparisons
def assert_values_equal(a, b, what: str) -> None:
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        assert isinstance(a, np.ndarray) and isinstance(b, np.ndarray), what
        assert a.dtype == b.dtype, f"{what}: dtype {a.dtype} != {b.dtype}"
        assert a.shape == b.shape, f"{what}: shape {a.shape} != {b.shape}"
        assert np.array_equal(a, b, equal_nan=a.dtype.kind in "fc"), f"{what}: values differ"
    elif isinstance(a, dict):
        assert isinstance(b, dict) and list(a) == list(b), f"{what}: keys {list(a)} != {list(b)}"
        for k in a:
            assert_values_equal(a[k], b[k], f"{what}[{k!r}]")
    elif isinstance(a, float) and np.isnan(a):
        assert isinstance(b, float) and np.isnan(b), what
    elif isinstance(a, list):
        assert isinstance(b, list) and len(a) == len(b), what
        for i, (x, y) in enumerate(zip(a, b)):
            assert_values_equal(x, y, f"{what}[{i}]")
    else:
        assert type(a) is type(b) and a == b, f"{what}: {a!r} != {b!r}"


def assert_maps_equal(a: Map, b: Map) -> None:
    assert list(a.keyframes) == list(b.keyframes)
    for kf_id, ka in a.keyframes.items():
        kb = b.keyframes[kf_id]
        for f in dataclasses.fields(KeyFrame):
            assert_values_equal(getattr(ka, f.name), getattr(kb, f.name), f"keyframe {kf_id}.{f.name}")
    n = len(a.points)
    assert len(b.points) == n
    va, vb = vars(a.points), vars(b.points)
    assert list(va) == list(vb)
    for name, value in va.items():
        if isinstance(value, np.ndarray):
            assert value.shape == vb[name].shape, f"points.{name} capacity"
            assert_values_equal(value[:n], vb[name][:n], f"points.{name}")
        else:
            assert_values_equal(value, vb[name], f"points.{name}")
    assert a.covisibility == b.covisibility
    assert list(a.covisibility) == list(b.covisibility)
    for i in a.covisibility:
        assert list(a.covisibility[i]) == list(b.covisibility[i]), f"covisibility[{i}] order"
    for name, value in vars(a).items():
        if name not in ("keyframes", "points", "covisibility"):
            assert_values_equal(value, vars(b)[name], f"map.{name}")


# ----------------------------------------------------------------------------- tampering
def rewrite_npz(root: Path, file: str, mutate, update_spec: bool = False) -> None:
    """Replace ``root/file`` by ``mutate(dict of arrays)`` and fix its size/checksum in map.json (so the
    loader gets past the checksum and must notice the change itself); ``update_spec`` also records
    the new arrays' dtypes/shapes."""
    with np.load(root / file, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    arrays = mutate(arrays)
    with open(root / file, "wb") as fh:
        np.savez(fh, **arrays)
    manifest = json.loads((root / "map.json").read_text())
    entry = manifest["files"][file]
    entry["bytes"] = (root / file).stat().st_size
    entry["sha256"] = hashlib.sha256((root / file).read_bytes()).hexdigest()
    if update_spec:
        entry["arrays"] = {k: {"dtype": a.dtype.str, "shape": list(a.shape)} for k, a in arrays.items()}
    (root / "map.json").write_text(json.dumps(manifest))
