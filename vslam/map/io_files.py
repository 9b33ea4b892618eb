"""The files of a saved map: size/checksum entries, fsync and the atomic swap into place (save);
size/checksum checks and guarded ``.npz`` reading (load)."""
from __future__ import annotations

import hashlib
import os
import shutil
import uuid
import zipfile
import zlib
from pathlib import Path

import numpy as np

from vslam.errors import MapFormatError
from vslam.map.io_format import MANIFEST_FILE


def file_entry(path: Path, arrays: dict[str, np.ndarray] | None) -> dict:
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


def fsync_file(path: Path) -> None:
    with open(path, "rb") as fh:
        os.fsync(fh.fileno())


def fsync_dir(path: Path) -> None:
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


def swap_into_place(tmp: Path, final: Path) -> None:
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
    fsync_dir(final.parent)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


def check_file(root: Path, name: str, entry: dict, verify: bool) -> None:
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


def read_npz(root: Path, name: str, entry: dict, keys: tuple[str, ...] | None = None) -> dict[str, np.ndarray]:
    """All arrays listed for ``name`` in the manifest (``keys``: only those), with their dtype and
    shape checked."""
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
                if keys is not None and key not in keys:
                    continue
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
