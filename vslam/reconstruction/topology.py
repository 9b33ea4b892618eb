"""Topological map: keyframes as nodes (with their pose), edges by kind, saved as JSON and drawn as PNG.

JSON layout (version 1)::

    {"version": 1,
     "nodes": [{"id": 0, "frame": 12, "T_world_cam": [[...4 numbers...] x 4]}, ...],
     "edges": [{"source": 0, "target": 1, "kind": "odometry", "weight": 1.0}, ...]}

Edge kinds: ``covisibility`` (weight = shared map points, as in ORB-SLAM's covisibility graph,
Mur-Artal et al., T-RO 2015), ``odometry`` (consecutive keyframes) and ``loop`` (verified loop
closures). Inputs are plain lists of dicts (or objects with those attributes), so any map can be
exported without this module knowing its classes.

Example:
    >>> nodes = nodes_from_poses(np.stack([np.eye(4)] * 2))
    >>> edges = [{"source": 0, "target": 1, "kind": "odometry", "weight": 1.0}]
    >>> write_topology("topology.json", nodes, edges)            # doctest: +SKIP
"""
from __future__ import annotations

import io
import json
import logging
from pathlib import Path
from typing import Any, Iterable

import numpy as np

from vslam.errors import MapFormatError, VslamError
from vslam.outputs import atomic_write_bytes, atomic_write_text

log = logging.getLogger(__name__)

EDGE_KINDS = ("covisibility", "odometry", "loop")
FORMAT_VERSION = 1
# drawing style per kind: colour, line width, z-order (loops on top, prominent)
_STYLE = {
    "covisibility": ("0.6", 0.6, 1),
    "odometry": ("tab:blue", 1.4, 2),
    "loop": ("tab:red", 3.0, 4),
}


def _get(obj: Any, key: str, default: Any = None) -> Any:
    if isinstance(obj, dict):
        return obj.get(key, default)
    return getattr(obj, key, default)


def nodes_from_poses(T_world_cam: np.ndarray, frames: Iterable[int] | None = None,
                     ids: Iterable[int] | None = None) -> list[dict]:
    """Node dicts for poses ``(N, 4, 4)``; ``ids`` default ``0..N-1``, ``frames`` default ``ids``."""
    T = np.asarray(T_world_cam, dtype=np.float64).reshape(-1, 4, 4)
    ids = list(range(len(T))) if ids is None else [int(i) for i in ids]
    frames = list(ids) if frames is None else [int(f) for f in frames]
    if not len(ids) == len(frames) == len(T):
        raise VslamError(f"nodes_from_poses: {len(T)} poses, {len(ids)} ids, {len(frames)} frames differ in number")
    return [{"id": i, "frame": f, "T_world_cam": T[k].copy()} for k, (i, f) in enumerate(zip(ids, frames))]


def normalize(nodes: Iterable[Any], edges: Iterable[Any], what: str = "topology") -> tuple[list[dict], list[dict]]:
    """Validated copies: nodes ``{"id": int, "frame": int, "T_world_cam": (4, 4) float64}``,
    edges ``{"source": int, "target": int, "kind": str, "weight": float}``.

    Raises :class:`VslamError` (``MapFormatError`` subclass) naming the bad node or edge.
    """
    out_nodes: list[dict] = []
    seen: set[int] = set()
    for k, n in enumerate(nodes):
        try:
            nid = int(_get(n, "id"))
            frame = int(_get(n, "frame", nid))
            T = np.asarray(_get(n, "T_world_cam"), dtype=np.float64)
        except (TypeError, ValueError):
            raise MapFormatError(f"{what}: node #{k} needs an integer id, frame and a 4x4 T_world_cam") from None
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise MapFormatError(f"{what}: node {nid} T_world_cam must be a finite 4x4 matrix, got shape {T.shape}")
        if nid in seen:
            raise MapFormatError(f"{what}: duplicate node id {nid}")
        seen.add(nid)
        out_nodes.append({"id": nid, "frame": frame, "T_world_cam": T})
    out_edges: list[dict] = []
    for k, e in enumerate(edges):
        try:
            s, t = int(_get(e, "source")), int(_get(e, "target"))
            kind = str(_get(e, "kind", "covisibility"))
            w = float(_get(e, "weight", 1.0))
        except (TypeError, ValueError):
            raise MapFormatError(f"{what}: edge #{k} needs integer source/target, a kind and a number weight") from None
        if kind not in EDGE_KINDS:
            raise MapFormatError(f"{what}: edge {s}-{t} has kind {kind!r}; use one of {EDGE_KINDS}")
        if s not in seen or t not in seen:
            raise MapFormatError(f"{what}: edge {s}-{t} ({kind}) joins a node id that is not in the node list")
        out_edges.append({"source": s, "target": t, "kind": kind, "weight": w})
    return out_nodes, out_edges


def write_topology(path_json: str | Path, nodes: Iterable[Any], edges: Iterable[Any]) -> Path:
    """Save the graph as JSON (see the module docstring); floats are written exactly (``repr``)."""
    nodes, edges = normalize(nodes, edges)
    doc = {
        "version": FORMAT_VERSION,
        "nodes": [{"id": n["id"], "frame": n["frame"], "T_world_cam": n["T_world_cam"].tolist()} for n in nodes],
        "edges": edges,
    }
    path = Path(path_json)
    if not path.parent.is_dir():
        raise VslamError(f"{path.parent}: output folder does not exist; create it first")
    return atomic_write_text(path, json.dumps(doc, indent=1))


def read_topology(path_json: str | Path) -> tuple[list[dict], list[dict]]:
    """``(nodes, edges)`` from :func:`write_topology`'s JSON (``T_world_cam`` as ``(4, 4)`` arrays)."""
    path = Path(path_json)
    if not path.is_file():
        raise VslamError(f"{path}: no such topology file")
    try:
        doc = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise MapFormatError(f"{path}: not valid JSON ({exc})") from None
    if not isinstance(doc, dict) or "nodes" not in doc or "edges" not in doc:
        raise MapFormatError(f"{path}: a topology file needs 'nodes' and 'edges' lists")
    if doc.get("version", FORMAT_VERSION) != FORMAT_VERSION:
        raise MapFormatError(f"{path}: topology format version {doc.get('version')} unsupported (expected {FORMAT_VERSION})")
    return normalize(doc["nodes"], doc["edges"], what=str(path))


def plane_axes(centres: np.ndarray) -> tuple[int, int]:
    """The two world axes along which the camera centres ``(N, 3)`` spread most (ascending order)."""
    extent = np.ptp(centres, axis=0) if len(centres) else np.zeros(3)
    a, b = np.argsort(-extent, kind="stable")[:2]
    return (int(a), int(b)) if a < b else (int(b), int(a))


def plot_topology(path_png: str | Path, nodes: Iterable[Any], edges: Iterable[Any], title: str = "topological map",
                  unit: str = "m") -> Path:
    """Draw the graph from above: nodes at the camera centres projected onto the plane of their
    two largest extents, edges coloured by kind (covisibility grey, odometry blue, loops thick red);
    ``unit`` of the axes (``arbitrary scale`` for a monocular map)."""
    from matplotlib.collections import LineCollection
    from matplotlib.figure import Figure  # no pyplot: no global backend state

    nodes, edges = normalize(nodes, edges)
    centres = np.array([n["T_world_cam"][:3, 3] for n in nodes]).reshape(-1, 3)
    ax_a, ax_b = plane_axes(centres)
    xy = centres[:, [ax_a, ax_b]]
    index = {n["id"]: k for k, n in enumerate(nodes)}

    fig = Figure(figsize=(7, 6))
    ax = fig.subplots()
    for kind in EDGE_KINDS:
        sel = [e for e in edges if e["kind"] == kind]
        if not sel:
            continue
        colour, width, z = _STYLE[kind]
        segs = np.array([[xy[index[e["source"]]], xy[index[e["target"]]]] for e in sel])
        widths = width
        if kind == "covisibility":  # thicker for more shared points, within [0.3, 1.5] x the base width
            w = np.array([e["weight"] for e in sel])
            widths = width * (0.3 + 1.2 * (w - w.min()) / max(np.ptp(w), 1e-9))
        ax.add_collection(LineCollection(segs, colors=colour, linewidths=widths, zorder=z,
                                         label=f"{kind} ({len(sel)})", alpha=0.9 if kind == "loop" else 0.7))
    if len(xy):
        ax.scatter(xy[:, 0], xy[:, 1], s=12, c="k", zorder=3, label=f"keyframes ({len(xy)})")
        ax.plot(*xy[0], "o", color="tab:green", ms=8, zorder=5, label="first")
        ax.plot(*xy[-1], "s", color="tab:orange", ms=7, zorder=5, label="last")
        ax.autoscale()
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel(f"{'xyz'[ax_a]} [{unit}]")
    ax.set_ylabel(f"{'xyz'[ax_b]} [{unit}]")
    ax.set_title(title)
    ax.grid(True, lw=0.3, alpha=0.5)
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)
    path = Path(path_png)
    if not path.parent.is_dir():
        raise VslamError(f"{path.parent}: output folder does not exist; create it first")
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
    return atomic_write_bytes(path, buf.getvalue())


__all__ = ["EDGE_KINDS", "nodes_from_poses", "normalize", "plane_axes", "plot_topology", "read_topology",
           "write_topology"]
