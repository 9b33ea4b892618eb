"""Packing a map into the arrays and layout of the format (the save side of :mod:`vslam.map.io`):
keyframe fields by storage kind, point-store columns, the covisibility edge list, Map attributes,
and the JSON checks of what goes into ``map.json``."""
from __future__ import annotations

import dataclasses
import json
import logging
from typing import Any

import numpy as np

from vslam.errors import MapFormatError
from vslam.geometry.camera import PinholeCamera
from vslam.map.io_format import (
    FORMAT_VERSION,
    JSON_SCALARS,
    KEYFRAME_FIELD_KINDS,
    KEYPOINT_COUNT_FIELD,
    MAP_STRUCTURES,
)
from vslam.map.keyframe import KeyFrame
from vslam.map.map import Map
from vslam.map.mappoint import MapPointStore

log = logging.getLogger(__name__)


def pack_keyframes(map: Map) -> tuple[dict[str, np.ndarray], dict[str, str], int]:  # noqa: A002
    """The arrays of ``keyframes.npz``, the ``{field: kind}`` layout, and the total keypoint count."""
    kfs = list(map.keyframes.values())
    for key, kf in map.keyframes.items():
        if kf.id != key:
            raise MapFormatError(f"cannot save the map: keyframe stored under id {key} has id {kf.id}")
    K = len(kfs)
    n_kp = np.array([len(getattr(kf, KEYPOINT_COUNT_FIELD)) for kf in kfs], dtype=np.int64)
    arrays: dict[str, np.ndarray] = {"n_keypoints": n_kp}
    layout: dict[str, str] = {}
    for f in dataclasses.fields(KeyFrame):
        name = f.name
        values = [getattr(kf, name) for kf in kfs]
        kind = KEYFRAME_FIELD_KINDS.get(name) or _infer_kind(name, values, n_kp)
        layout[name] = kind
        if kind == "scalar":
            arr = np.asarray(values) if K else np.zeros(0)
            if arr.ndim != 1 or arr.dtype.kind not in "biufU":
                raise MapFormatError(f"cannot save KeyFrame.{name}: expected one number/string per keyframe, "
                                     f"got dtype {arr.dtype} shape {arr.shape}")
            arrays[name] = arr
        elif kind in ("stacked", "keypoint"):
            present = np.array([v is not None for v in values], dtype=bool)
            rows = [np.asarray(v) for v in values if v is not None]
            if kind == "keypoint":
                for kf, v, n in zip(kfs, values, n_kp.tolist()):
                    if v is not None and (np.ndim(v) == 0 or len(v) != n):
                        raise MapFormatError(f"cannot save KeyFrame.{name}: keyframe {kf.id} has {np.shape(v)} values "
                                             f"for its {n} keypoints ({KEYPOINT_COUNT_FIELD})")
            arrays[name] = _join(name, rows, stack=kind == "stacked")
            arrays[f"{name}.present"] = present
        elif kind == "dict":
            texts = []
            for i, (kf, v) in enumerate(zip(kfs, values)):
                texts.append(_pack_dict(name, i, kf.id, v, arrays))
            arrays[name] = np.array(texts, dtype=str) if texts else np.zeros(0, dtype="<U1")
        else:  # pragma: no cover - KEYFRAME_FIELD_KINDS holds only known kinds
            raise MapFormatError(f"KeyFrame.{name}: unknown storage kind {kind!r}")
    return arrays, layout, int(n_kp.sum())


def _infer_kind(name: str, values: list, n_kp: np.ndarray) -> str:
    """Storage kind of a KeyFrame field that format version 1 does not document, from its values."""
    present = [v for v in values if v is not None]
    if not present:
        kind = "keypoint"
    elif all(isinstance(v, np.ndarray) for v in present):
        lens_ok = all(v.ndim >= 1 and len(v) == n for v, n in zip(values, n_kp) if v is not None)
        kind = "keypoint" if lens_ok else "stacked"
    elif all(isinstance(v, (bool, int, float, str, np.generic)) for v in values):
        kind = "scalar"
    elif all(isinstance(v, dict) for v in values):
        kind = "dict"
    else:
        raise MapFormatError(
            f"cannot save KeyFrame.{name}: values of type {sorted({type(v).__name__ for v in values})} are not "
            "supported by map format 1 (use numbers, strings, NumPy arrays or dicts); update vslam/map/io_format.py"
        )
    log.warning("KeyFrame.%s is not documented in map format %d; saving it as %r (update KEYFRAME_FIELD_KINDS "
                "and FORMAT.md)", name, FORMAT_VERSION, kind)
    return kind


def _join(name: str, rows: list[np.ndarray], stack: bool) -> np.ndarray:
    """Concatenate (or stack) per-keyframe arrays, refusing mixed dtypes/trailing shapes (not exact)."""
    if not rows:
        return np.zeros(0)
    ref = next((r for r in rows if len(r) or stack), rows[0])
    tail = ref.shape if stack else ref.shape[1:]
    for r in rows:
        if not stack and len(r) == 0:
            continue  # empty keyframes take the common dtype/trailing shape
        if r.dtype != ref.dtype or (r.shape if stack else r.shape[1:]) != tail:
            raise MapFormatError(
                f"cannot save KeyFrame.{name} exactly: keyframes hold {ref.dtype}{list(ref.shape)} and "
                f"{r.dtype}{list(r.shape)} arrays; make the frontend produce one dtype/shape per field"
            )
    if stack:
        return np.stack(rows)
    rows = [r if len(r) else np.zeros((0,) + tail, ref.dtype) for r in rows]
    return np.concatenate(rows)


def _pack_dict(field: str, index: int, kf_id: int, value: Any, arrays: dict[str, np.ndarray]) -> str:
    """JSON text of a keyframe's dict field; NumPy array values go to their own npz members."""
    if value is None:
        return "null"
    if not isinstance(value, dict):
        raise MapFormatError(f"cannot save keyframe {kf_id} {field}: expected a dict, got {type(value).__name__}")
    out = {}
    for j, (key, v) in enumerate(value.items()):
        if not isinstance(key, str):
            raise MapFormatError(f"cannot save keyframe {kf_id} {field}[{key!r}]: keys must be strings")
        if isinstance(v, np.ndarray):
            if v.dtype.kind not in "biufcUS":
                raise MapFormatError(f"cannot save keyframe {kf_id} {field}[{key!r}]: dtype {v.dtype} needs pickle")
            member = f"{field}.{index}.{j}"
            arrays[member] = v
            out[key] = {"__ndarray__": member}
        else:
            check_json(f"keyframe {kf_id} {field}[{key!r}]", v)
            if isinstance(v, dict) and set(v) == {"__ndarray__"}:
                raise MapFormatError(f"cannot save keyframe {kf_id} {field}[{key!r}]: the key '__ndarray__' is reserved")
            out[key] = v
    return json.dumps(out, allow_nan=True)


def pack_points(store: MapPointStore) -> tuple[dict[str, np.ndarray], dict]:
    """The used rows of every array column of the store, and its layout (rows, capacity, columns)."""
    n = len(store)
    arrays: dict[str, np.ndarray] = {}
    columns: dict[str, bool] = {}
    scalars: dict[str, Any] = {}
    cap = None
    for name, value in vars(store).items():
        if isinstance(value, np.ndarray):
            arrays[name] = value[:n]
            columns[name] = True
            cap = value.shape[0] if cap is None else cap
        elif value is None:
            columns[name] = False  # e.g. no descriptors (KLT mode)
        elif isinstance(value, JSON_SCALARS) or isinstance(value, np.integer):
            scalars[name] = value.item() if isinstance(value, np.generic) else value
        else:
            raise MapFormatError(f"cannot save MapPointStore.{name} of type {type(value).__name__}; update vslam/map/io_format.py")
    for name in arrays:
        rows = vars(store)[name].shape[0]
        if rows != cap:
            raise MapFormatError(f"cannot save MapPointStore.{name}: {rows} rows, the other columns {cap}")
    return arrays, {"rows": n, "capacity": int(cap if cap is not None else n), "columns": columns,
                    "attributes": scalars}


def pack_covisibility(covisibility: dict[int, dict[int, int]]) -> dict[str, np.ndarray]:
    """``nodes (M,)``: the graph's keyframes in dict order; ``edges (E, 3)``: ``(i, j, w)`` in dict order
    (every directed entry ``covisibility[i][j] = w``, so insertion order and asymmetry survive)."""
    nodes = np.fromiter(covisibility.keys(), dtype=np.int64, count=len(covisibility))
    counts = [len(links) for links in covisibility.values()]
    total = int(sum(counts))
    edges = np.empty((total, 3), dtype=np.int64)
    edges[:, 0] = np.repeat(nodes, counts)
    edges[:, 1] = np.fromiter((j for links in covisibility.values() for j in links), dtype=np.int64, count=total)
    edges[:, 2] = np.fromiter((w for links in covisibility.values() for w in links.values()), dtype=np.int64, count=total)
    return {"nodes": nodes, "edges": edges}


def pack_map_attributes(map: Map) -> dict:  # noqa: A002
    out = {}
    for name, value in vars(map).items():
        if name in MAP_STRUCTURES:
            continue
        if isinstance(value, np.generic):
            value = value.item()
        if not isinstance(value, JSON_SCALARS):
            raise MapFormatError(f"cannot save Map.{name} of type {type(value).__name__}: map format "
                                 f"{FORMAT_VERSION} stores only numbers/strings besides {MAP_STRUCTURES}")
        out[name] = value
    out["gravity_aligned"] = bool(map.gravity_aligned)  # visual-inertial maps: world z up (FORMAT.md)
    return out


def camera_to_json(camera: PinholeCamera) -> dict:
    out = {}
    for f in dataclasses.fields(PinholeCamera):
        v = getattr(camera, f.name)
        out[f.name] = [float(x) for x in v] if isinstance(v, (tuple, list, np.ndarray)) else v
    check_json("camera", out)
    return out


def check_json(what: str, value: Any) -> None:
    """Refuse values that JSON would not give back equal (numpy scalars, tuples, non-str keys)."""
    try:
        back = json.loads(json.dumps(value, allow_nan=True))
    except (TypeError, ValueError) as exc:
        raise MapFormatError(f"cannot save {what}: not JSON-serializable ({exc})") from exc
    if not _json_equal(back, value):
        raise MapFormatError(f"cannot save {what}: it would not load back equal from JSON "
                             "(tuples, NumPy scalars or non-string keys); use lists, Python numbers and str keys")


def _json_equal(a: Any, b: Any) -> bool:
    if type(a) is not type(b) and not (isinstance(a, float) and isinstance(b, float)):
        return False
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(_json_equal(a[k], b[k]) for k in a)
    if isinstance(a, list):
        return len(a) == len(b) and all(_json_equal(x, y) for x, y in zip(a, b))
    if isinstance(a, float) and np.isnan(a):
        return bool(np.isnan(b))
    return a == b
