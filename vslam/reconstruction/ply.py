"""PLY point clouds and triangle meshes, pure NumPy (no Open3D needed for I/O).

The format is Greg Turk's "PLY polygon file format" (Stanford, 1994): an ASCII header naming
elements (``vertex``, ``face``) and their properties, then the data as ASCII lines or packed
binary records. Written here: ``vertex`` with ``x y z`` (``float``, or ``double`` for float64
input), optional ``nx ny nz`` and optional ``uchar red green blue``; for meshes a ``face`` element
with ``list uchar int vertex_indices``. Binary little-endian by default, ASCII on request.
Read back: ASCII, binary little- and big-endian, any extra scalar properties (ignored), other
elements (skipped), and faces with any list types (triangulated as fans when not triangles).

Example:
    >>> import numpy as np, tempfile, os
    >>> p = os.path.join(tempfile.mkdtemp(), "tri.ply")
    >>> _ = write_ply(p, np.eye(3, dtype=np.float32), faces=np.array([[0, 1, 2]]))
    >>> read_ply(p).faces
    array([[0, 1, 2]], dtype=int32)
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vslam.errors import MapFormatError, VslamError
from vslam.outputs import atomic_path

log = logging.getLogger(__name__)

# PLY scalar type names (both spellings of the spec) -> NumPy type codes without byte order
_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}
_FORMATS = {"ascii": None, "binary_little_endian": "<", "binary_big_endian": ">"}


@dataclass
class PlyData:
    """What a PLY file holds. ``points (N, 3)``, ``colors (N, 3) uint8`` RGB or None,
    ``normals (N, 3)`` or None, ``faces (F, 3) int32`` vertex indices or None (a point cloud)."""

    points: np.ndarray
    colors: np.ndarray | None = None
    normals: np.ndarray | None = None
    faces: np.ndarray | None = None

    @property
    def is_mesh(self) -> bool:
        return self.faces is not None and len(self.faces) > 0


# ---------------------------------------------------------------------------------------------
# writing
# ---------------------------------------------------------------------------------------------
def _check_array(name: str, arr: np.ndarray | None, n: int | None, cols: int = 3) -> np.ndarray | None:
    if arr is None:
        return None
    arr = np.asarray(arr)
    if arr.ndim != 2 or arr.shape[1] != cols or (n is not None and len(arr) != n):
        want = f"({n if n is not None else 'N'}, {cols})"
        raise VslamError(f"PLY {name} must have shape {want}, got {arr.shape}")
    return arr


def write_ply(
    path: str | Path,
    points: np.ndarray,
    colors: np.ndarray | None = None,
    normals: np.ndarray | None = None,
    faces: np.ndarray | None = None,
    binary: bool = True,
) -> Path:
    """Write a point cloud (``faces`` None) or a triangle mesh to ``path``; returns the path.

    Args:
        points: ``(N, 3)`` vertex positions; float64 is written as ``double``, anything else as
            ``float`` (so float32 and float64 input both round-trip exactly).
        colors: ``(N, 3)`` RGB, ``uint8`` (floats in ``[0, 1]`` are scaled by 255 and rounded).
        normals: ``(N, 3)`` per-vertex normals (written as ``float``).
        faces: ``(F, 3)`` integer vertex indices of triangles.
        binary: binary little-endian (default) or ASCII.
    """
    points = _check_array("points", points, None)
    n = len(points)
    colors = _check_array("colors", colors, n)
    normals = _check_array("normals", normals, n)
    faces = _check_array("faces", faces, None)
    if colors is not None and colors.dtype != np.uint8:
        if np.issubdtype(colors.dtype, np.floating) and (len(colors) == 0 or colors.max() <= 1.0):
            colors = np.clip(np.round(colors * 255.0), 0, 255)
        colors = np.clip(colors, 0, 255).astype(np.uint8)
    if faces is not None and len(faces) and (faces.min() < 0 or faces.max() >= n):
        raise VslamError(f"PLY faces index vertices outside 0..{n - 1}")

    coord = "f8" if points.dtype == np.float64 else "f4"
    fields: list[tuple[str, str]] = [("x", coord), ("y", coord), ("z", coord)]
    if normals is not None:
        fields += [("nx", "f4"), ("ny", "f4"), ("nz", "f4")]
    if colors is not None:
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    names = {"f4": "float", "f8": "double", "u1": "uchar"}
    header = ["ply", f"format {'binary_little_endian' if binary else 'ascii'} 1.0", "comment written by vslam",
              f"element vertex {n}"]
    header += [f"property {names[t]} {name}" for name, t in fields]
    if faces is not None:
        header += [f"element face {len(faces)}", "property list uchar int vertex_indices"]
    header.append("end_header")

    vert = np.empty(n, dtype=[(name, "<" + t) for name, t in fields])
    vert["x"], vert["y"], vert["z"] = points.T
    if normals is not None:
        vert["nx"], vert["ny"], vert["nz"] = np.asarray(normals, dtype=np.float32).T
    if colors is not None:
        vert["red"], vert["green"], vert["blue"] = colors.T

    path = Path(path)
    if not path.parent.is_dir():
        raise VslamError(f"{path.parent}: output folder does not exist; create it first")
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:  # a failed write leaves an existing file whole
        fh.write(("\n".join(header) + "\n").encode("ascii"))
        if binary:
            fh.write(vert.tobytes())
            if faces is not None:
                rec = np.empty(len(faces), dtype=[("n", "u1"), ("v", "<i4", (3,))])
                rec["n"] = 3
                rec["v"] = faces
                fh.write(rec.tobytes())
        else:
            _write_ascii_rows(fh, vert, fields)
            if faces is not None and len(faces):
                np.savetxt(fh, np.column_stack([np.full(len(faces), 3), faces]).astype(np.int64), fmt="%d")
    log.debug("wrote %s: %d vertices, %s faces", path, n, len(faces) if faces is not None else "no")
    return path


def _write_ascii_rows(fh, vert: np.ndarray, fields: list[tuple[str, str]]) -> None:
    """ASCII vertex lines; floats with ``repr`` precision (``%.9g`` float32, ``%.17g`` float64)."""
    if len(vert) == 0:
        return
    fmts = {"f4": "%.9g", "f8": "%.17g", "u1": "%d"}
    table = np.stack([vert[name].astype(np.float64) for name, _ in fields], axis=1)  # exact for f4, u1
    np.savetxt(fh, table, fmt=" ".join(fmts[t] for _, t in fields))


def write_point_cloud(path: str | Path, points: np.ndarray, colors: np.ndarray | None = None,
                      normals: np.ndarray | None = None, binary: bool = True) -> Path:
    """A point cloud PLY (see :func:`write_ply`)."""
    return write_ply(path, points, colors=colors, normals=normals, binary=binary)


def write_mesh(path: str | Path, vertices: np.ndarray, faces: np.ndarray, colors: np.ndarray | None = None,
               normals: np.ndarray | None = None, binary: bool = True) -> Path:
    """A triangle mesh PLY (see :func:`write_ply`); ``faces (F, 3)`` index ``vertices (V, 3)``."""
    return write_ply(path, vertices, colors=colors, normals=normals, faces=np.asarray(faces).reshape(-1, 3),
                     binary=binary)


# ---------------------------------------------------------------------------------------------
# reading
# ---------------------------------------------------------------------------------------------
@dataclass
class _Element:
    name: str
    count: int
    props: list[tuple]  # ("scalar", name, code) or ("list", name, count_code, item_code)


def _parse_header(fh, path: Path) -> tuple[str, list[_Element]]:
    first = fh.readline()
    if first.strip() != b"ply":
        raise MapFormatError(f"{path}: not a PLY file (it does not start with 'ply')")
    fmt = None
    elements: list[_Element] = []
    while True:
        line = fh.readline()
        if not line:
            raise MapFormatError(f"{path}: PLY header has no end_header line (truncated file?)")
        words = line.decode("ascii", errors="replace").split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "end_header":
            break
        try:
            if words[0] == "format":
                fmt = words[1]
                if fmt not in _FORMATS:
                    raise MapFormatError(f"{path}: unknown PLY format {fmt!r}")
            elif words[0] == "element":
                elements.append(_Element(words[1], int(words[2]), []))
                if elements[-1].count < 0:
                    raise ValueError("negative element count")
            elif words[0] == "property":
                if not elements:
                    raise MapFormatError(f"{path}: PLY property before any element")
                if words[1] == "list":
                    elements[-1].props.append(("list", words[4], _PLY_TYPES[words[2]], _PLY_TYPES[words[3]]))
                else:
                    elements[-1].props.append(("scalar", words[2], _PLY_TYPES[words[1]]))
            else:
                raise MapFormatError(f"{path}: unexpected PLY header line {line.strip()!r}")
        except (IndexError, KeyError, ValueError):
            raise MapFormatError(f"{path}: malformed PLY header line {line.strip()!r}") from None
    if fmt is None:
        raise MapFormatError(f"{path}: PLY header has no format line")
    return fmt, elements


def _vertex_arrays(rec: np.ndarray, path: Path) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    names = rec.dtype.names or ()
    if not {"x", "y", "z"} <= set(names):
        raise MapFormatError(f"{path}: PLY vertex element has no x, y, z properties")
    dt = np.result_type(rec["x"].dtype, np.float32)
    points = np.stack([rec["x"], rec["y"], rec["z"]], axis=1).astype(dt)
    colors = None
    for r, g, b in (("red", "green", "blue"), ("r", "g", "b"), ("diffuse_red", "diffuse_green", "diffuse_blue")):
        if {r, g, b} <= set(names):
            c = np.stack([rec[r], rec[g], rec[b]], axis=1)
            if np.issubdtype(c.dtype, np.floating):
                c = np.round(np.clip(c, 0, 1) * 255.0)
            colors = c.astype(np.uint8)
            break
    normals = None
    if {"nx", "ny", "nz"} <= set(names):
        normals = np.stack([rec["nx"], rec["ny"], rec["nz"]], axis=1)
    return points, colors, normals


def _triangulate(polys: list[np.ndarray]) -> np.ndarray:
    """Fan-triangulate polygons (list of index arrays) into ``(F, 3)``."""
    tris = [np.stack([np.full(len(p) - 2, p[0]), p[1:-1], p[2:]], axis=1) for p in polys if len(p) >= 3]
    return np.concatenate(tris).astype(np.int32) if tris else np.zeros((0, 3), np.int32)


def _read_binary_element(buf: memoryview, pos: int, el: _Element, order: str, path: Path):
    """Returns (records or list of per-row dicts, new position)."""
    if all(p[0] == "scalar" for p in el.props):
        dt = np.dtype([(p[1], order + p[2]) for p in el.props])
        end = pos + dt.itemsize * el.count
        if end > len(buf):
            raise MapFormatError(f"{path}: PLY data ends inside element '{el.name}' (truncated file)")
        return np.frombuffer(buf, dtype=dt, count=el.count, offset=pos), end
    # a single list property of triangles (the usual face element): try the fixed-size layout
    if len(el.props) == 1 and el.props[0][0] == "list":
        _, name, cnt, item = el.props[0]
        dt = np.dtype([("n", order + cnt), ("v", order + item, (3,))])
        end = pos + dt.itemsize * el.count
        if end <= len(buf):
            rec = np.frombuffer(buf, dtype=dt, count=el.count, offset=pos)
            if np.all(rec["n"] == 3):
                return {name: rec["v"].astype(np.int32)}, end
    # general case: walk row by row
    rows: dict[str, list] = {p[1]: [] for p in el.props}
    for _ in range(el.count):
        for p in el.props:
            if p[0] == "scalar":
                t = np.dtype(order + p[2])
                if pos + t.itemsize > len(buf):
                    raise MapFormatError(f"{path}: PLY data ends inside element '{el.name}' (truncated file)")
                rows[p[1]].append(np.frombuffer(buf, t, 1, pos)[0])
                pos += t.itemsize
            else:
                tc, ti = np.dtype(order + p[2]), np.dtype(order + p[3])
                if pos + tc.itemsize > len(buf):
                    raise MapFormatError(f"{path}: PLY data ends inside element '{el.name}' (truncated file)")
                k = int(np.frombuffer(buf, tc, 1, pos)[0])
                pos += tc.itemsize
                if pos + k * ti.itemsize > len(buf):
                    raise MapFormatError(f"{path}: PLY data ends inside element '{el.name}' (truncated file)")
                rows[p[1]].append(np.frombuffer(buf, ti, k, pos).astype(np.int64))
                pos += k * ti.itemsize
    return rows, pos


def _read_ascii_element(tokens: list[bytes], pos: int, el: _Element, path: Path):
    if all(p[0] == "scalar" for p in el.props):
        k = len(el.props)
        end = pos + k * el.count
        if end > len(tokens):
            raise MapFormatError(f"{path}: PLY data ends inside element '{el.name}' (truncated file)")
        try:
            table = np.array(tokens[pos:end], dtype=np.float64).reshape(el.count, k)
        except ValueError:
            raise MapFormatError(f"{path}: non-numeric value in PLY element '{el.name}'") from None
        rec = np.empty(el.count, dtype=[(p[1], p[2]) for p in el.props])
        for j, p in enumerate(el.props):
            rec[p[1]] = table[:, j]
        return rec, end
    rows: dict[str, list] = {p[1]: [] for p in el.props}
    try:
        for _ in range(el.count):
            for p in el.props:
                if p[0] == "scalar":
                    rows[p[1]].append(float(tokens[pos]))
                    pos += 1
                else:
                    k = int(tokens[pos])
                    rows[p[1]].append(np.array(tokens[pos + 1:pos + 1 + k], dtype=np.int64))
                    if len(rows[p[1]][-1]) != k:
                        raise IndexError
                    pos += 1 + k
    except (IndexError, ValueError):
        raise MapFormatError(f"{path}: PLY element '{el.name}' is truncated or malformed") from None
    return rows, pos


def read_ply(path: str | Path) -> PlyData:
    """Read a PLY point cloud or mesh (ASCII or binary). Raises :class:`MapFormatError` when broken."""
    path = Path(path)
    if not path.is_file():
        raise VslamError(f"{path}: no such PLY file")
    with open(path, "rb") as fh:
        fmt, elements = _parse_header(fh, path)
        body = fh.read()
    order = _FORMATS[fmt]
    vertex = faces_raw = None
    if order is None:
        tokens = body.split()
        pos = 0
        for el in elements:
            data, pos = _read_ascii_element(tokens, pos, el, path)
            if el.name == "vertex":
                vertex = data
            elif el.name == "face":
                faces_raw = data
    else:
        buf = memoryview(body)
        pos = 0
        for el in elements:
            data, pos = _read_binary_element(buf, pos, el, order, path)
            if el.name == "vertex":
                vertex = data
            elif el.name == "face":
                faces_raw = data
    if vertex is None or not isinstance(vertex, np.ndarray):
        raise MapFormatError(f"{path}: PLY file has no (scalar) vertex element")
    points, colors, normals = _vertex_arrays(vertex, path)
    faces = None
    if faces_raw is not None:
        key = next((k for k in ("vertex_indices", "vertex_index") if k in faces_raw), None)
        if key is None:
            raise MapFormatError(f"{path}: PLY face element has no vertex_indices list")
        f = faces_raw[key]
        faces = f if isinstance(f, np.ndarray) else _triangulate(f)
        if len(faces) and (faces.min() < 0 or faces.max() >= len(points)):
            raise MapFormatError(f"{path}: PLY faces index vertices outside 0..{len(points) - 1}")
    return PlyData(points, colors, normals, faces)


__all__ = ["PlyData", "read_ply", "write_mesh", "write_ply", "write_point_cloud"]
