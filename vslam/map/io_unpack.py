"""Unpacking the arrays and layout of the format back into a map (the load side of
:mod:`vslam.map.io`), checking every shape, count and reference against ``map.json``."""
from __future__ import annotations

import dataclasses
import json
import logging
from pathlib import Path

import numpy as np

from vslam.errors import MapFormatError
from vslam.geometry.camera import PinholeCamera
from vslam.map.io_format import (
    COVISIBILITY_FILE,
    KEYFRAME_FIELD_SHAPES,
    KEYFRAMES_FILE,
    KINDS,
    MANIFEST_FILE,
    POINTS_FILE,
)
from vslam.map.keyframe import KeyFrame
from vslam.map.map import Map
from vslam.map.mappoint import MapPointStore

log = logging.getLogger(__name__)


def _expect(root: Path, file: str, arrays: dict, key: str, shape: tuple) -> np.ndarray:
    """``arrays[key]`` with its leading dimensions checked (None = any)."""
    if key not in arrays:
        raise MapFormatError(f"{root / file}: missing array {key!r}")
    a = arrays[key]
    ok = a.ndim >= len(shape) and all(s is None or s == d for s, d in zip(shape, a.shape))
    if not ok:
        want = "(" + ", ".join("*" if s is None else str(s) for s in shape) + (", ...)" if shape else "...)")
        raise MapFormatError(f"{root / file}: array {key!r} has the wrong shape {a.shape}, expected {want}")
    return a


def unpack_keyframes(root: Path, manifest: dict, arrays: dict, n_points: int) -> list[KeyFrame]:
    layout: dict[str, str] = manifest["keyframe_fields"]
    K = manifest["counts"].get("keyframes")
    if not isinstance(K, int):
        raise MapFormatError(f"{root / MANIFEST_FILE}: counts.keyframes is missing")
    n_kp = _expect(root, KEYFRAMES_FILE, arrays, "n_keypoints", (K,)).astype(np.int64)
    if np.any(n_kp < 0) or int(n_kp.sum()) != manifest["counts"].get("keypoints"):
        raise MapFormatError(f"{root / KEYFRAMES_FILE}: keypoint counts disagree with {MANIFEST_FILE}")
    ours = {f.name: f for f in dataclasses.fields(KeyFrame)}
    unknown = [n for n in layout if n not in ours]
    if unknown:
        raise MapFormatError(f"{root / MANIFEST_FILE}: keyframe fields {unknown} are unknown to this build of KeyFrame "
                             "(saved by a newer vslam?)")
    missing = [n for n, f in ours.items() if n not in layout
               and f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING]
    if missing:
        raise MapFormatError(f"{root / MANIFEST_FILE}: the map does not store keyframe fields {missing} "
                             "(saved by an older vslam?)")
    columns: dict[str, list] = {}
    for name, kind in layout.items():
        if kind not in KINDS:
            raise MapFormatError(f"{root / MANIFEST_FILE}: keyframe field {name!r} has unknown kind {kind!r}")
        if kind == "scalar":
            columns[name] = _expect(root, KEYFRAMES_FILE, arrays, name, (K,)).tolist()
        elif kind in ("stacked", "keypoint"):
            present = _expect(root, KEYFRAMES_FILE, arrays, f"{name}.present", (K,)).astype(bool)
            if kind == "stacked":
                data = _expect(root, KEYFRAMES_FILE, arrays, name, (int(present.sum()),))
                _check_tail(root, name, data, present.any())
                rows = iter(data) if present.any() else iter(())
            else:
                sizes = n_kp[present]
                data = _expect(root, KEYFRAMES_FILE, arrays, name, (int(sizes.sum()),))
                _check_tail(root, name, data, present.any())
                rows = iter(np.split(data, np.cumsum(sizes)[:-1])) if present.any() else iter(())
            columns[name] = [next(rows).copy() if p else None for p in present.tolist()]
        else:  # dict
            texts = _expect(root, KEYFRAMES_FILE, arrays, name, (K,))
            columns[name] = [_unpack_dict(root, name, str(t), arrays) for t in texts.tolist()]
    ids = columns.get("id", list(range(K)))
    if len(set(ids)) != K:
        raise MapFormatError(f"{root / KEYFRAMES_FILE}: keyframe ids are not unique")
    keyframes = [KeyFrame(**{name: col[i] for name, col in columns.items()}) for i in range(K)]
    if "point_ids" in layout and K:
        all_ids = arrays["point_ids"]
        if all_ids.size and (all_ids.max() >= n_points or all_ids.min() < -1):
            raise MapFormatError(f"{root / KEYFRAMES_FILE}: point_ids reference point {int(all_ids.max())} but "
                                 f"{POINTS_FILE} holds {n_points} points")
    return keyframes


def _check_tail(root: Path, name: str, data: np.ndarray, any_present: bool) -> None:
    """Per-keyframe/per-keypoint shape of the documented fields (e.g. poses must be 4x4)."""
    want = KEYFRAME_FIELD_SHAPES.get(name)
    if want is not None and any_present and data.shape[1:] != want:
        expected = "(" + ", ".join(["*", *map(str, want)]) + ")"
        raise MapFormatError(f"{root / KEYFRAMES_FILE}: array {name!r} has the wrong shape {data.shape}, "
                             f"expected {expected}")


def _unpack_dict(root: Path, field: str, text: str, arrays: dict) -> dict | None:
    try:
        value = json.loads(text)
    except json.JSONDecodeError as exc:
        raise MapFormatError(f"{root / KEYFRAMES_FILE}: {field!r} holds invalid JSON: {exc}") from exc
    if value is None:
        return None
    if not isinstance(value, dict):
        raise MapFormatError(f"{root / KEYFRAMES_FILE}: {field!r} holds {type(value).__name__}, expected a JSON object")
    for key, v in value.items():
        if isinstance(v, dict) and set(v) == {"__ndarray__"}:
            member = v["__ndarray__"]
            if member not in arrays:
                raise MapFormatError(f"{root / KEYFRAMES_FILE}: missing array {member!r} ({field}[{key!r}])")
            value[key] = arrays[member].copy()
    return value


_MAX_SPARE_CAPACITY = 1 << 20  # point_store rows allocated beyond 4x the saved ones at most


def unpack_points(root: Path, manifest: dict, arrays: dict) -> MapPointStore:
    layout = manifest["point_store"]
    n, cap = layout.get("rows"), layout.get("capacity")
    columns = layout.get("columns")
    if not isinstance(n, int) or not isinstance(cap, int) or n < 0 or cap < n or not isinstance(columns, dict):
        raise MapFormatError(f"{root / MANIFEST_FILE}: malformed point_store {layout}")
    if cap > max(4 * n, _MAX_SPARE_CAPACITY):  # checked before allocating: a crafted capacity is no MemoryError
        raise MapFormatError(f"{root / MANIFEST_FILE}: point_store capacity {cap} is implausible for {n} rows "
                             f"(at most {max(4 * n, _MAX_SPARE_CAPACITY)}); the manifest is corrupted")
    store = MapPointStore(capacity=cap)
    ours = vars(store)
    for name, saved in columns.items():
        if name not in ours:
            raise MapFormatError(f"{root / POINTS_FILE}: column {name!r} is unknown to this build of MapPointStore "
                                 "(saved by a newer vslam?)")
        if not saved:
            setattr(store, name, None)
            continue
        a = _expect(root, POINTS_FILE, arrays, name, (n,))
        current = ours[name]
        if isinstance(current, np.ndarray):
            if current.dtype != a.dtype or current.shape[1:] != a.shape[1:]:
                raise MapFormatError(f"{root / POINTS_FILE}: column {name!r} is {a.dtype}{list(a.shape[1:])} per "
                                     f"point, this build expects {current.dtype}{list(current.shape[1:])}")
            current[:n] = a
        else:
            full = np.zeros((store._cap,) + a.shape[1:], dtype=a.dtype)
            full[:n] = a
            setattr(store, name, full)
    missing = [k for k, v in ours.items() if isinstance(v, np.ndarray) and k not in columns]
    if missing:
        raise MapFormatError(f"{root / POINTS_FILE}: the map does not store point columns {missing} (saved by an older vslam?)")
    for name, value in layout.get("attributes", {}).items():
        if name not in ours:
            raise MapFormatError(f"{root / MANIFEST_FILE}: MapPointStore attribute {name!r} is unknown to this build")
        setattr(store, name, value)
    if len(store) != n:
        raise MapFormatError(f"{root / MANIFEST_FILE}: point_store rows {n} disagree with its attributes")
    return store


def unpack_covisibility(root: Path, manifest: dict, arrays: dict) -> dict[int, dict[int, int]]:
    counts = manifest["counts"]
    nodes = _expect(root, COVISIBILITY_FILE, arrays, "nodes", (counts.get("covisibility_nodes"),))
    edges = _expect(root, COVISIBILITY_FILE, arrays, "edges", (counts.get("covisibility_edges"), 3))
    graph: dict[int, dict[int, int]] = {int(i): {} for i in nodes.tolist()}
    if len(graph) != len(nodes):
        raise MapFormatError(f"{root / COVISIBILITY_FILE}: duplicate nodes")
    for i, j, w in edges.tolist():
        links = graph.get(i)
        if links is None:
            raise MapFormatError(f"{root / COVISIBILITY_FILE}: edge ({i}, {j}) starts at keyframe {i}, not a graph node")
        if j not in graph:
            raise MapFormatError(f"{root / COVISIBILITY_FILE}: edge ({i}, {j}) ends at keyframe {j}, not a graph node")
        links[j] = w
    return graph


#: |coordinate| of a map point or keyframe centre beyond this (metres) is no map (as vslam.trajectory.MAX_COORDINATE)
MAX_COORDINATE = 1e12


def check_references(root: Path, slam_map: Map) -> None:
    """Every covisibility node is a keyframe, every keyframe pose is finite and rigid, and every
    live map point's position is finite and within :data:`MAX_COORDINATE`."""
    n = len(slam_map.points)
    alive = np.asarray(slam_map.points.alive[:n], bool)
    position = np.asarray(slam_map.points.position[:n], float)
    bad = alive & ~np.all(np.isfinite(position) & (np.abs(position) <= MAX_COORDINATE), axis=1)
    if bad.any():
        raise MapFormatError(f"{root / POINTS_FILE}: {int(bad.sum())} map points (e.g. point {int(np.argmax(bad))}) "
                             f"have positions that are not finite (or beyond {MAX_COORDINATE:.0e} m); the map is corrupted")
    missing = [k for k in slam_map.covisibility if k not in slam_map.keyframes]
    if missing:
        raise MapFormatError(f"{root / COVISIBILITY_FILE}: graph node {missing[0]} is not a keyframe of "
                             f"{KEYFRAMES_FILE}; the map is corrupted")
    for kf in slam_map.keyframes.values():
        T = np.asarray(kf.T_world_cam, dtype=float)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)) or np.abs(T).max() > MAX_COORDINATE \
                or not np.allclose(T[3], [0, 0, 0, 1]) \
                or not np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-3):
            raise MapFormatError(f"{root / KEYFRAMES_FILE}: keyframe {kf.id} pose is not a finite rigid "
                                 "transform; the map is corrupted")


def unpack_map_attributes(root: Path, manifest: dict, slam_map: Map) -> None:
    ours = vars(slam_map)
    for name, value in manifest["map_attributes"].items():
        if name not in ours:
            raise MapFormatError(f"{root / MANIFEST_FILE}: Map attribute {name!r} is unknown to this build")
        if name == "gravity_aligned" and not isinstance(value, bool):
            raise MapFormatError(f"{root / MANIFEST_FILE}: map_attributes.gravity_aligned must be true or false, "
                                 f"got {value!r}; the manifest is corrupted")
        setattr(slam_map, name, value)


def camera_from_json(root: Path, data: dict | None) -> PinholeCamera | None:
    if data is None:
        return None
    try:
        kwargs = {k: tuple(v) if isinstance(v, list) else v for k, v in data.items()}
        camera = PinholeCamera(**kwargs)
    except (TypeError, ValueError, AttributeError) as exc:
        raise MapFormatError(f"{root / MANIFEST_FILE}: camera {data} is malformed: {exc}") from None
    numbers = {k: getattr(camera, k, None) for k in ("fx", "fy", "cx", "cy", "width", "height")}
    ok = all(isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v) for v in numbers.values())
    if not ok or numbers["fx"] <= 0 or numbers["fy"] <= 0 or numbers["width"] < 1 or numbers["height"] < 1 \
            or not all(isinstance(numbers[k], int) for k in ("width", "height")):
        raise MapFormatError(f"{root / MANIFEST_FILE}: camera {numbers} is invalid (positive finite focal "
                             "lengths and whole-number image size needed); the map is corrupted")
    return camera
