"""Read the vertices of a PLY point cloud (``sparse.ply``): ASCII or binary, ``x y z [red green blue]``.

Only the ``vertex`` element is read (it must be the first element, as every writer does); other
vertex properties are skipped. Binary files are read with one structured NumPy ``frombuffer``.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from vslam.errors import MapFormatError

_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
    "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}


def read_ply_points(path: str | Path, max_points: int | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """``(xyz (N, 3) float64, rgb (N, 3) uint8 or None)`` from a PLY file.

    Args:
        max_points: keep at most this many points (an even subsample), for plotting.

    Raises:
        MapFormatError: not a PLY file, no ``vertex`` element or ``x y z``, truncated data.
    """
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise MapFormatError(f"{path}: cannot read the point cloud ({exc.strerror})") from None
    end = raw.find(b"end_header")
    if not raw.startswith(b"ply") or end < 0:
        raise MapFormatError(f"{path}: not a PLY file (no 'ply' magic or no 'end_header')")
    body_start = raw.index(b"\n", end) + 1
    header = raw[:end].decode("ascii", "replace").splitlines()
    fmt = None
    n = None
    props: list[tuple[str, str]] = []
    element = None
    first_element = None
    for line in header:
        parts = line.split()
        if not parts:
            continue
        if parts[0] == "format":
            fmt = parts[1]
        elif parts[0] == "element":
            element = parts[1]
            first_element = first_element or element
            if element == "vertex":
                try:
                    n = int(parts[2])
                except (IndexError, ValueError):
                    n = -1
                if n < 0:
                    raise MapFormatError(f"{path}: malformed PLY header line {line.strip()!r}: the vertex "
                                         "count must be a whole number >= 0")
        elif parts[0] == "property" and element == "vertex":
            if parts[1] == "list":
                raise MapFormatError(f"{path}: list properties on vertices are not supported")
            if parts[1] not in _TYPES:
                raise MapFormatError(f"{path}: unknown PLY property type {parts[1]!r}")
            props.append((parts[2], _TYPES[parts[1]]))
    names = [p[0] for p in props]
    if n is None or first_element != "vertex" or not {"x", "y", "z"} <= set(names):
        raise MapFormatError(f"{path}: needs a first 'vertex' element with x, y, z properties")
    if fmt == "ascii":
        text = raw[body_start:].decode("ascii", "replace").split("\n")[:n]
        try:
            data = np.loadtxt(text, ndmin=2, usecols=range(len(props))) if n else np.zeros((0, len(props)))
        except ValueError as exc:
            raise MapFormatError(f"{path}: malformed vertex line ({exc})") from None
        if len(data) != n:
            raise MapFormatError(f"{path}: header says {n} vertices, found {len(data)} (truncated?)")
        col = {name: data[:, i] for i, name in enumerate(names)}
    elif fmt in ("binary_little_endian", "binary_big_endian"):
        order = "<" if fmt == "binary_little_endian" else ">"
        dtype = np.dtype([(name, order + t) for name, t in props])
        if len(raw) - body_start < n * dtype.itemsize:
            raise MapFormatError(f"{path}: header says {n} vertices but the data is shorter (truncated?)")
        arr = np.frombuffer(raw, dtype=dtype, count=n, offset=body_start)
        col = {name: arr[name] for name in names}
    else:
        raise MapFormatError(f"{path}: unknown PLY format {fmt!r}")
    xyz = np.stack([col["x"], col["y"], col["z"]], 1).astype(np.float64)
    rgb = None
    if {"red", "green", "blue"} <= set(names):
        rgb = np.clip(np.stack([col["red"], col["green"], col["blue"]], 1), 0, 255).astype(np.uint8)
    keep = np.all(np.isfinite(xyz), axis=1)
    xyz, rgb = xyz[keep], (rgb[keep] if rgb is not None else None)
    if max_points is not None and len(xyz) > max_points:
        idx = np.linspace(0, len(xyz) - 1, max_points).astype(int)
        xyz, rgb = xyz[idx], (rgb[idx] if rgb is not None else None)
    return xyz, rgb
