"""Save and load a SLAM map: a versioned, documented, pickle-free format (see ``FORMAT.md``).

``save_map(map, DIR)`` writes ``DIR/map/``::

    map.json          format name, version, counts, camera, metadata, field layout, file checksums
    keyframes.npz     per-keyframe scalars (K,), stacked poses (K, 4, 4), per-keypoint arrays
                      concatenated over keyframes (offsets = cumsum of ``n_keypoints``)
    points.npz        the used rows of every MapPointStore column
    covisibility.npz  the covisibility graph as an ordered edge list (i, j, w)
    database.npz      optional: the bag-of-words KeyframeDatabase (its own ``save`` format)

Arrays are uncompressed ``.npz`` read back with ``allow_pickle=False``; every file's size and
SHA-256 are in ``map.json``. The layout follows the classes generically: every
``dataclasses.fields(KeyFrame)`` field and every array column of ``MapPointStore`` is saved, so a
field added later is saved too (its storage kind is inferred from its values and recorded in
``map.json``). ``KEYFRAME_FIELD_KINDS`` / ``POINT_COLUMNS`` list the documented ones; a test fails
when the classes grow a field that is not documented there.

The directory is written to a temporary sibling, flushed, and renamed into place, so an
interrupted save never leaves a half-written ``DIR/map``.

Example:
    >>> path = save_map(slam_map, "runs/office", camera=cam, metadata={"sequence": "office"})  # doctest: +SKIP
    >>> slam_map, db, cam, meta = load_map("runs/office")                                       # doctest: +SKIP
"""
from __future__ import annotations

import dataclasses
import datetime as _dt
import hashlib
import json
import logging
import os
import shutil
import time
import uuid
import zipfile
import zlib
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from vslam.errors import MapFormatError
from vslam.geometry.camera import PinholeCamera
from vslam.map.keyframe import KeyFrame
from vslam.map.map import Map
from vslam.map.mappoint import MapPointStore
from vslam.map.segments import segments_from_json, segments_to_json

if TYPE_CHECKING:
    from vslam.map.config import DatabaseConfig
    from vslam.map.database import KeyframeDatabase

log = logging.getLogger(__name__)

FORMAT_NAME = "vslam-map"
FORMAT_VERSION = 2  # 2: the segment table (map.json "segments"); version 1 maps still load
READABLE_VERSIONS = (1, 2)
MAP_DIRNAME = "map"
MANIFEST_FILE = "map.json"
KEYFRAMES_FILE = "keyframes.npz"
POINTS_FILE = "points.npz"
COVISIBILITY_FILE = "covisibility.npz"
DATABASE_FILE = "database.npz"

# Storage kind of each KeyFrame field in format version 1 (documented in FORMAT.md):
#   scalar    one value per keyframe -> array (K,)
#   stacked   one fixed-shape array per keyframe (or None) -> stacked (K_present, ...)
#   keypoint  one (N_k, ...) array per keyframe (or None) -> concatenated (sum N_k present, ...)
#   dict      a dict of JSON values / NumPy arrays -> (K,) JSON strings + one member per array
KEYFRAME_FIELD_KINDS: dict[str, str] = {
    "id": "scalar",
    "frame_index": "scalar",
    "timestamp": "scalar",
    "T_world_cam": "stacked",
    "uv": "keypoint",
    "uv_undist": "keypoint",
    "descriptors": "keypoint",
    "octave": "keypoint",
    "depth": "keypoint",
    "point_ids": "keypoint",
    "segment": "scalar",
    "u_right": "keypoint",
    "bad": "scalar",
    "extra": "dict",
}
# Shape of one keyframe's value (stacked) or of one keypoint's value (keypoint), checked on load.
KEYFRAME_FIELD_SHAPES: dict[str, tuple[int, ...]] = {
    "T_world_cam": (4, 4), "uv": (2,), "uv_undist": (2,), "octave": (), "depth": (), "point_ids": (), "u_right": (),
}
KEYPOINT_COUNT_FIELD = "uv"  # its length is the keyframe's keypoint count N_k
# MapPointStore columns documented in format version 1 (any array column is saved generically).
POINT_COLUMNS = ("position", "normal", "min_distance", "max_distance", "found", "visible", "n_obs",
                 "first_kf", "last_seen_kf", "alive", "color", "descriptor")
# Map attributes handled explicitly; any other scalar attribute is saved in map.json.
MAP_STRUCTURES = ("keyframes", "points", "covisibility", "segments")

_KINDS = ("scalar", "stacked", "keypoint", "dict")
_JSON_SCALARS = (bool, int, float, str, type(None))


# ============================================================================ save
def save_map(
    map: Map,  # noqa: A002 - the brief's public name
    directory: str | Path,
    *,
    database: KeyframeDatabase | None = None,
    camera: PinholeCamera | None = None,
    metadata: dict | None = None,
) -> Path:
    """Write ``map`` (and optionally its BoW ``database``, ``camera``, JSON ``metadata``) to ``directory/map``.

    An existing ``directory/map`` is replaced only once the new one is complete.

    Returns:
        The path of the written ``map`` directory.
    Raises:
        MapFormatError: a value the format cannot store exactly (non-JSON metadata, keyframes whose
            arrays of one field differ in dtype, an unsupported field type).
    """
    t0 = time.perf_counter()
    directory = Path(directory)
    final = directory / MAP_DIRNAME
    metadata = {} if metadata is None else metadata
    _check_json("metadata", metadata)
    directory.mkdir(parents=True, exist_ok=True)
    tmp = directory / f".{MAP_DIRNAME}.tmp-{uuid.uuid4().hex[:12]}"
    tmp.mkdir()
    try:
        kf_arrays, kf_layout, n_keypoints = _pack_keyframes(map)
        pt_arrays, pt_layout = _pack_points(map.points)
        graph_arrays = _pack_covisibility(map.covisibility)
        map_attrs = _pack_map_attributes(map)
        files: dict[str, dict] = {}
        for name, arrays in ((KEYFRAMES_FILE, kf_arrays), (POINTS_FILE, pt_arrays), (COVISIBILITY_FILE, graph_arrays)):
            with open(tmp / name, "wb") as fh:
                np.savez(fh, **arrays)
                fh.flush()
                os.fsync(fh.fileno())
            files[name] = _file_entry(tmp / name, arrays)
        if database is not None:
            database.save(tmp / DATABASE_FILE)
            _fsync_file(tmp / DATABASE_FILE)
            files[DATABASE_FILE] = _file_entry(tmp / DATABASE_FILE, None)
        manifest = {
            "format": FORMAT_NAME,
            "version": FORMAT_VERSION,
            "created_utc": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
            "vslam_version": _vslam_version(),
            "counts": {
                "keyframes": len(map.keyframes),
                "keypoints": int(n_keypoints),
                "point_rows": len(map.points),
                "points_alive": int(map.points.n_alive),
                "covisibility_nodes": int(graph_arrays["nodes"].shape[0]),
                "covisibility_edges": int(graph_arrays["edges"].shape[0]),
            },
            "camera": None if camera is None else _camera_to_json(camera),
            "metadata": metadata,
            "keyframe_fields": kf_layout,
            "point_store": pt_layout,
            "map_attributes": map_attrs,
            "segments": segments_to_json(map),
            "database": DATABASE_FILE if database is not None else None,
            "files": files,
        }
        text = json.dumps(manifest, indent=1, allow_nan=True)
        with open(tmp / MANIFEST_FILE, "w") as fh:
            fh.write(text + "\n")
            fh.flush()
            os.fsync(fh.fileno())
        _fsync_dir(tmp)
        _swap_into_place(tmp, final)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    log.info("map saved to %s: %d keyframes, %d keypoints, %d points, %.1f MB in %.2f s", final,
             len(map.keyframes), n_keypoints, len(map.points),
             sum(f["bytes"] for f in files.values()) / 1e6, time.perf_counter() - t0)
    return final


def _pack_keyframes(map: Map) -> tuple[dict[str, np.ndarray], dict[str, str], int]:  # noqa: A002
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
            "supported by map format 1 (use numbers, strings, NumPy arrays or dicts); update vslam/map/io.py"
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
            _check_json(f"keyframe {kf_id} {field}[{key!r}]", v)
            if isinstance(v, dict) and set(v) == {"__ndarray__"}:
                raise MapFormatError(f"cannot save keyframe {kf_id} {field}[{key!r}]: the key '__ndarray__' is reserved")
            out[key] = v
    return json.dumps(out, allow_nan=True)


def _pack_points(store: MapPointStore) -> tuple[dict[str, np.ndarray], dict]:
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
        elif isinstance(value, _JSON_SCALARS) or isinstance(value, np.integer):
            scalars[name] = value.item() if isinstance(value, np.generic) else value
        else:
            raise MapFormatError(f"cannot save MapPointStore.{name} of type {type(value).__name__}; update vslam/map/io.py")
    for name in arrays:
        rows = vars(store)[name].shape[0]
        if rows != cap:
            raise MapFormatError(f"cannot save MapPointStore.{name}: {rows} rows, the other columns {cap}")
    return arrays, {"rows": n, "capacity": int(cap if cap is not None else n), "columns": columns,
                    "attributes": scalars}


def _pack_covisibility(covisibility: dict[int, dict[int, int]]) -> dict[str, np.ndarray]:
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


def _pack_map_attributes(map: Map) -> dict:  # noqa: A002
    out = {}
    for name, value in vars(map).items():
        if name in MAP_STRUCTURES:
            continue
        if isinstance(value, np.generic):
            value = value.item()
        if not isinstance(value, _JSON_SCALARS):
            raise MapFormatError(f"cannot save Map.{name} of type {type(value).__name__}: map format "
                                 f"{FORMAT_VERSION} stores only numbers/strings besides {MAP_STRUCTURES}")
        out[name] = value
    return out


def _camera_to_json(camera: PinholeCamera) -> dict:
    out = {}
    for f in dataclasses.fields(PinholeCamera):
        v = getattr(camera, f.name)
        out[f.name] = [float(x) for x in v] if isinstance(v, (tuple, list, np.ndarray)) else v
    _check_json("camera", out)
    return out


def _check_json(what: str, value: Any) -> None:
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


def _file_entry(path: Path, arrays: dict[str, np.ndarray] | None) -> dict:
    entry = {"bytes": path.stat().st_size, "sha256": _sha256(path)}
    if arrays is not None:
        entry["arrays"] = {k: {"dtype": a.dtype.str, "shape": list(a.shape)} for k, a in arrays.items()}
    return entry


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        while chunk := fh.read(1 << 22):
            h.update(chunk)
    return h.hexdigest()


def _fsync_file(path: Path) -> None:
    with open(path, "rb") as fh:
        os.fsync(fh.fileno())


def _fsync_dir(path: Path) -> None:
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:  # pragma: no cover - platforms without directory fds
        return
    try:
        os.fsync(fd)
    except OSError:  # pragma: no cover
        pass
    finally:
        os.close(fd)


def _swap_into_place(tmp: Path, final: Path) -> None:
    """Rename the finished ``tmp`` to ``final``; an existing ``final`` is moved aside first and
    deleted only after the new map is in place (restored if the rename fails)."""
    old = None
    if final.exists():
        old = final.parent / f".{final.name}.old-{uuid.uuid4().hex[:12]}"
        os.replace(final, old)
    try:
        os.replace(tmp, final)
    except BaseException:
        if old is not None and not final.exists():
            os.replace(old, final)
        raise
    _fsync_dir(final.parent)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


def _vslam_version() -> str:
    try:
        from vslam import __version__
    except ImportError:  # pragma: no cover
        return "unknown"
    return __version__


# ============================================================================ load
def load_map(
    directory: str | Path,
    *,
    database_config: DatabaseConfig | None = None,
    verify_checksums: bool = True,
) -> tuple[Map, KeyframeDatabase | None, PinholeCamera | None, dict]:
    """Read a map written by :func:`save_map`.

    Args:
        directory: the ``DIR`` given to :func:`save_map` (or ``DIR/map`` itself).
        database_config: query settings for the loaded KeyframeDatabase (default settings if None).
        verify_checksums: compare each file's SHA-256 with ``map.json`` (sizes are always checked).
    Returns:
        ``(map, database or None, camera or None, metadata)``.
    Raises:
        MapFormatError: missing/truncated/corrupted files, unsupported version, missing or misshapen
            arrays, inconsistent contents; the message names the file and what is wrong.
    """
    t0 = time.perf_counter()
    root = _resolve(Path(directory))
    manifest = _read_manifest(root)
    files = manifest["files"]
    for name in (KEYFRAMES_FILE, POINTS_FILE, COVISIBILITY_FILE):
        if name not in files:
            raise MapFormatError(f"{root / MANIFEST_FILE}: 'files' does not list {name}")
    for name, entry in files.items():
        _check_file(root, name, entry, verify_checksums)

    kf_arrays = _read_npz(root, KEYFRAMES_FILE, files[KEYFRAMES_FILE])
    pt_arrays = _read_npz(root, POINTS_FILE, files[POINTS_FILE])
    graph_arrays = _read_npz(root, COVISIBILITY_FILE, files[COVISIBILITY_FILE])

    slam_map = Map()
    points = _unpack_points(root, manifest, pt_arrays)
    keyframes = _unpack_keyframes(root, manifest, kf_arrays, len(points))
    slam_map.keyframes = {kf.id: kf for kf in keyframes}
    slam_map.points = points
    slam_map.covisibility = _unpack_covisibility(root, manifest, graph_arrays)
    _check_references(root, slam_map)
    _unpack_map_attributes(root, manifest, slam_map)
    if manifest["version"] >= 2:  # version 1 (no table): one row per segment, built by its own run
        slam_map.segments = segments_from_json(str(root / MANIFEST_FILE), manifest.get("segments"))

    database = None
    if manifest.get("database"):
        from vslam.map.database import KeyframeDatabase

        db_name = manifest["database"]
        if db_name not in files:
            raise MapFormatError(f"{root / MANIFEST_FILE}: database {db_name!r} is not listed in 'files'")
        try:
            database = (KeyframeDatabase.load(root / db_name) if database_config is None
                        else KeyframeDatabase.load(root / db_name, database_config))
        except MapFormatError:
            raise
        except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile, zlib.error) as exc:
            raise MapFormatError(f"{root / db_name} is unreadable (truncated or corrupted): {exc}") from exc
    camera = _camera_from_json(root, manifest.get("camera"))
    metadata = manifest.get("metadata") or {}
    log.info("map loaded from %s: %d keyframes, %d points in %.2f s", root, len(keyframes), len(points),
             time.perf_counter() - t0)
    return slam_map, database, camera, metadata


def _resolve(directory: Path) -> Path:
    if (directory / MANIFEST_FILE).is_file():
        return directory
    root = directory / MAP_DIRNAME
    if (root / MANIFEST_FILE).is_file():
        return root
    if not directory.exists():
        raise MapFormatError(f"map directory {directory} does not exist")
    hint = ""
    leftovers = sorted(p.name for p in directory.glob(f".{MAP_DIRNAME}.*")) if directory.is_dir() else []
    if leftovers:
        hint = f" (found {', '.join(leftovers)}: left by an interrupted save)"
    where = root if root.is_dir() else directory
    raise MapFormatError(f"{where / MANIFEST_FILE} is missing: {directory} does not hold a saved vslam map{hint}")


def _read_manifest(root: Path) -> dict:
    path = root / MANIFEST_FILE
    try:
        manifest = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise MapFormatError(f"{path} is unreadable or not valid JSON (truncated?): {exc}") from exc
    if not isinstance(manifest, dict):
        raise MapFormatError(f"{path}: expected a JSON object")
    if manifest.get("format") != FORMAT_NAME:
        raise MapFormatError(f"{path}: format {manifest.get('format')!r} is not {FORMAT_NAME!r}")
    version = manifest.get("version")
    if version not in READABLE_VERSIONS:
        raise MapFormatError(f"{path}: unsupported version {version} (this build reads versions "
                             f"{' and '.join(str(v) for v in READABLE_VERSIONS)})")
    for key in ("counts", "keyframe_fields", "point_store", "map_attributes", "files"):
        if not isinstance(manifest.get(key), dict):
            raise MapFormatError(f"{path}: missing or malformed {key!r}")
    return manifest


def _check_file(root: Path, name: str, entry: dict, verify: bool) -> None:
    path = root / name
    if not isinstance(entry, dict):
        raise MapFormatError(f"{root / MANIFEST_FILE}: malformed entry for {name} in 'files'")
    if Path(name).name != name:
        raise MapFormatError(f"{root / MANIFEST_FILE}: file name {name!r} must not contain a directory")
    if not path.is_file():
        raise MapFormatError(f"{path} is missing (listed in {MANIFEST_FILE})")
    size = path.stat().st_size
    if size != entry.get("bytes"):
        what = "truncated" if isinstance(entry.get("bytes"), int) and size < entry["bytes"] else "the wrong size"
        raise MapFormatError(f"{path} is {what}: {size} bytes, {MANIFEST_FILE} says {entry.get('bytes')}")
    if verify and _sha256(path) != entry.get("sha256"):
        raise MapFormatError(f"{path}: checksum mismatch (SHA-256 differs from {MANIFEST_FILE}): the file is corrupted")


def _read_npz(root: Path, name: str, entry: dict) -> dict[str, np.ndarray]:
    """All arrays listed for ``name`` in the manifest, with their dtype and shape checked."""
    path = root / name
    spec = entry.get("arrays")
    if not isinstance(spec, dict):
        raise MapFormatError(f"{root / MANIFEST_FILE}: no array list for {name}")
    out = {}
    try:
        _check_npz_sizes(path)
        with np.load(path, allow_pickle=False) as data:
            present = set(data.files)
            for key, s in spec.items():
                if key not in present:
                    raise MapFormatError(f"{path}: missing array {key!r}")
                a = data[key]
                if a.dtype.str != s.get("dtype") or list(a.shape) != s.get("shape"):
                    raise MapFormatError(f"{path}: array {key!r} is {a.dtype.str}{list(a.shape)}, "
                                         f"{MANIFEST_FILE} says {s.get('dtype')}{s.get('shape')}")
                out[key] = a
            extra = present - set(spec)
            if extra:
                raise MapFormatError(f"{path}: unexpected arrays {sorted(extra)} not listed in {MANIFEST_FILE}")
    except MapFormatError:
        raise
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile, zipfile.LargeZipFile, zlib.error) as exc:
        raise MapFormatError(f"{path} is unreadable (truncated or corrupted): {exc}") from exc
    return out


def _check_npz_sizes(path: Path) -> None:
    """Before anything is allocated: every member is stored uncompressed (as :func:`save_map` writes
    it, so its size is bounded by the file's, which ``map.json`` fixes) and its ``.npy`` header
    claims no more bytes than the member holds (a crafted shape would otherwise allocate first)."""
    from numpy.lib import format as npy

    size = path.stat().st_size
    with zipfile.ZipFile(path) as zf:
        for info in zf.infolist():
            if info.compress_type != zipfile.ZIP_STORED or info.file_size > size:
                raise MapFormatError(f"{path}: member {info.filename!r} is compressed or larger than the file; "
                                     "maps are written uncompressed by vslam")
            with zf.open(info) as fh:
                version = npy.read_magic(fh)
                if version not in ((1, 0), (2, 0), (3, 0)):
                    raise MapFormatError(f"{path}: member {info.filename!r} has .npy version {version}")
                reader = npy.read_array_header_1_0 if version == (1, 0) else npy.read_array_header_2_0
                shape, _, dtype = reader(fh)
                if dtype.hasobject:
                    raise MapFormatError(f"{path}: member {info.filename!r} holds Python objects; not a vslam map")
                claimed = int(np.prod(shape, dtype=object)) * dtype.itemsize
                if claimed > info.file_size:
                    raise MapFormatError(f"{path}: array {info.filename!r} claims shape {shape} ({claimed} bytes) "
                                         f"but holds {info.file_size} bytes; the map is corrupted")


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


def _unpack_keyframes(root: Path, manifest: dict, arrays: dict, n_points: int) -> list[KeyFrame]:
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
        if kind not in _KINDS:
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


def _unpack_points(root: Path, manifest: dict, arrays: dict) -> MapPointStore:
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


def _unpack_covisibility(root: Path, manifest: dict, arrays: dict) -> dict[int, dict[int, int]]:
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


def _check_references(root: Path, slam_map: Map) -> None:
    """Every covisibility node is a keyframe and every keyframe pose is finite and rigid."""
    missing = [k for k in slam_map.covisibility if k not in slam_map.keyframes]
    if missing:
        raise MapFormatError(f"{root / COVISIBILITY_FILE}: graph node {missing[0]} is not a keyframe of "
                             f"{KEYFRAMES_FILE}; the map is corrupted")
    for kf in slam_map.keyframes.values():
        T = np.asarray(kf.T_world_cam, dtype=float)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)) or not np.allclose(T[3], [0, 0, 0, 1]) \
                or not np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-3):
            raise MapFormatError(f"{root / KEYFRAMES_FILE}: keyframe {kf.id} pose is not a finite rigid "
                                 "transform; the map is corrupted")


def _unpack_map_attributes(root: Path, manifest: dict, slam_map: Map) -> None:
    ours = vars(slam_map)
    for name, value in manifest["map_attributes"].items():
        if name not in ours:
            raise MapFormatError(f"{root / MANIFEST_FILE}: Map attribute {name!r} is unknown to this build")
        setattr(slam_map, name, value)


def _camera_from_json(root: Path, data: dict | None) -> PinholeCamera | None:
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
