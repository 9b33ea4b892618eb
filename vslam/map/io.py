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
``map.json``). ``KEYFRAME_FIELD_KINDS`` / ``POINT_COLUMNS`` (in :mod:`vslam.map.io_format`) list the
documented ones; a test fails when the classes grow a field that is not documented there.

The directory is written to a temporary sibling, flushed, and renamed into place, so an
interrupted save never leaves a half-written ``DIR/map``.

Example:
    >>> path = save_map(slam_map, "runs/office", camera=cam, metadata={"sequence": "office"})  # doctest: +SKIP
    >>> slam_map, db, cam, meta = load_map("runs/office")                                       # doctest: +SKIP
"""
from __future__ import annotations

import datetime as _dt
import json
import logging
import os
import shutil
import time
import uuid
import zipfile
import zlib
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from vslam.errors import MapFormatError
from vslam.geometry.camera import PinholeCamera
from vslam.map.io_files import (  # the helpers under the names save_map / load_map use
    check_file as _check_file,
    file_entry as _file_entry,
    fsync_dir as _fsync_dir,
    fsync_file as _fsync_file,
    read_npz as _read_npz,
    swap_into_place as _swap_into_place,
)
from vslam.map.io_format import (
    COVISIBILITY_FILE,
    DATABASE_FILE,
    FORMAT_NAME,
    FORMAT_VERSION,
    KEYFRAME_FIELD_KINDS,
    KEYFRAME_FIELD_SHAPES,
    KEYFRAMES_FILE,
    KEYPOINT_COUNT_FIELD,
    MANIFEST_FILE,
    MAP_DIRNAME,
    MAP_STRUCTURES,
    READABLE_VERSIONS,
    POINT_COLUMNS,
    POINTS_FILE,
)
from vslam.map.io_pack import (
    camera_to_json as _camera_to_json,
    check_json as _check_json,
    pack_covisibility as _pack_covisibility,
    pack_keyframes as _pack_keyframes,
    pack_map_attributes as _pack_map_attributes,
    pack_points as _pack_points,
)
from vslam.map.io_unpack import (
    camera_from_json as _camera_from_json,
    check_references as _check_references,
    unpack_covisibility as _unpack_covisibility,
    unpack_keyframes as _unpack_keyframes,
    unpack_map_attributes as _unpack_map_attributes,
    unpack_points as _unpack_points,
)
from vslam.map.io_inertial import check_inertial_extras, check_inertial_metadata
from vslam.map.map import Map
from vslam.map.segments import segments_from_json, segments_to_json

if TYPE_CHECKING:
    from vslam.map.config import DatabaseConfig
    from vslam.map.database import KeyframeDatabase

__all__ = [
    "COVISIBILITY_FILE", "DATABASE_FILE", "FORMAT_NAME", "FORMAT_VERSION", "KEYFRAMES_FILE",
    "KEYFRAME_FIELD_KINDS", "KEYFRAME_FIELD_SHAPES", "KEYPOINT_COUNT_FIELD", "MANIFEST_FILE", "MAP_DIRNAME",
    "MAP_STRUCTURES", "POINTS_FILE", "POINT_COLUMNS", "load_map", "load_run_map", "save_map",
]

log = logging.getLogger(__name__)

#: map.json holds counts, the camera, metadata and the segment table: kilobytes, never this much
MAX_MANIFEST_BYTES = 64 << 20


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
    check_inertial_metadata("save_map", metadata)
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
    check_inertial_extras(root / KEYFRAMES_FILE, keyframes)
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
        stray = [i for i in database.keyframe_ids if i not in slam_map.keyframes]
        if stray:
            raise MapFormatError(f"{root / db_name}: {len(stray)} keyframe ids (e.g. {stray[0]}) are not keyframes "
                                 "of the map (corrupted or from another map)")
    camera = _camera_from_json(root, manifest.get("camera"))
    metadata = manifest.get("metadata") or {}
    if not isinstance(metadata, dict):
        raise MapFormatError(f"{root / MANIFEST_FILE}: metadata must be a JSON object")
    check_inertial_metadata(root / MANIFEST_FILE, metadata)
    log.info("map loaded from %s: %d keyframes, %d points in %.2f s", root, len(keyframes), len(points),
             time.perf_counter() - t0)
    return slam_map, database, camera, metadata


def load_keyframe_poses(directory: str | Path, verify_checksums: bool = True) -> dict[int, np.ndarray]:
    """``{keyframe id: T_world_cam}`` of the good (not ``bad``) keyframes of a map written by
    :func:`save_map`, read from ``keyframes.npz`` alone (its size and checksum checked as
    :func:`load_map` does): what ``vslam map``'s finalize needs of each session's own map, at a
    fifth of a whole load (60 ms against 0.30 s for the 16 sessions of the synthetic fleet)."""
    root = _resolve(Path(directory))
    manifest = _read_manifest(root)
    entry = manifest["files"].get(KEYFRAMES_FILE)
    if entry is None:
        raise MapFormatError(f"{root / MANIFEST_FILE}: 'files' does not list {KEYFRAMES_FILE}")
    _check_file(root, KEYFRAMES_FILE, entry, verify_checksums)
    arrays = _read_npz(root, KEYFRAMES_FILE, entry, keys=("id", "bad", "T_world_cam", "T_world_cam.present"))
    ids, bad, present = arrays["id"], arrays["bad"].astype(bool), arrays["T_world_cam.present"].astype(bool)
    T = arrays["T_world_cam"]
    if not (len(ids) == len(bad) == len(present) and int(present.sum()) == len(T) and T.shape[1:] == (4, 4)):
        raise MapFormatError(f"{root / KEYFRAMES_FILE}: keyframe ids, flags and poses disagree in length")
    rows = np.cumsum(present) - 1
    return {int(k): T[r].copy() for k, b, p, r in zip(ids.tolist(), bad.tolist(), present.tolist(), rows.tolist())
            if p and not b}


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
        if path.stat().st_size > MAX_MANIFEST_BYTES:
            raise MapFormatError(f"{path}: {path.stat().st_size} bytes is not a map manifest (at most "
                                 f"{MAX_MANIFEST_BYTES}; corrupted or not a vslam map)")
        manifest = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise MapFormatError(f"{path} is unreadable or not valid JSON (truncated?): {exc}") from exc
    except RecursionError:  # JSON nested thousands of levels deep
        raise MapFormatError(f"{path}: nested too deeply to be a map manifest (corrupted)") from None
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


def load_run_map(run_dir: str | Path, what: str, purpose: str, database_config: DatabaseConfig | None = None):
    """:func:`load_map` of a run folder a user named (``DIR`` or ``DIR/map``): one-line
    :class:`MapFormatError` when the folder is missing or its map has no keyframes (``"{run_dir}:
    {what} has no keyframes; nothing to {purpose}"``). Returns ``(map, database, camera, metadata)``.

    While another command writes the folder (``vslam run --map M -o M``) this waits for it a bounded
    time, then says which command it is (:func:`vslam.outputs.reading_run_dir`, :class:`OutputError`);
    when the last run into it did not complete (stopped), the last complete map, kept in
    ``DIR/.previous-run/``, is read, with a warning that says so."""
    from vslam.outputs import LOCK_NAME, PREVIOUS_NAME, last_complete_run, reading_run_dir, refuse_if_written

    run_dir = Path(run_dir)
    # DIR/map names the map of the run folder DIR (which holds the lock and .previous-run/)
    inner = run_dir.name == MAP_DIRNAME and not (run_dir / MAP_DIRNAME).is_dir() and not any(
        (run_dir / n).exists() for n in (LOCK_NAME, PREVIOUS_NAME))
    folder = run_dir.parent if inner else run_dir
    if not run_dir.exists() and not (inner and (folder / PREVIOUS_NAME / MAP_DIRNAME).is_dir()):
        raise MapFormatError(f"{run_dir}: no such map folder (give the --output folder of a `vslam run`)")
    try:
        with reading_run_dir(folder, what):
            source, why = last_complete_run(folder)
            if why is not None and (source / MAP_DIRNAME / MANIFEST_FILE).is_file():
                log.warning("%s: the last run into this folder did not complete (%s); %s is read from the last "
                            "complete run, kept in %s", folder, why, what, source)
            else:
                source = run_dir
            slam_map, database, camera, metadata = load_map(source, database_config=database_config)
    except MapFormatError:
        refuse_if_written(folder, what)  # a run started writing it meanwhile: say that, not "missing"
        raise
    if not slam_map.keyframes:
        raise MapFormatError(f"{run_dir}: {what} has no keyframes; nothing to {purpose}")
    return slam_map, database, camera, metadata
