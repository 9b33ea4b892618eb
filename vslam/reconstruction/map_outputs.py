"""The map files every run writes: the sparse point cloud, the topological map and the saved map.

* ``sparse.ply``: alive map points with their colour (binary PLY).
* ``topology.json`` / ``topology.png``: a graph of places, one node per keyframe, with
  ``odometry`` edges (consecutive keyframes of a map segment), ``covisibility`` edges (keyframes
  sharing at least ``min_covisibility`` map points, weight = shared points) and ``loop`` edges.
* ``map/``: the versioned map (:mod:`vslam.map.io`), reloadable for relocalization.
"""
from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np

from vslam.map.io import save_map
from vslam.map.map import Map
from vslam.reconstruction.sparse import export_sparse
from vslam.reconstruction.topology import plot_topology, write_topology

log = logging.getLogger(__name__)


def _segment_rows(slam_map: Map):
    """Keyframe id -> the row of the map's segment table holding it (None outside every row). A
    merged map's sessions share one segment (welded into one frame) but keep a row each, and
    consecutive ids across two sessions are no odometry (``vslam map``'s topological map drew a chord
    from each session's last keyframe to the next one's first)."""
    ranges = np.array([r.keyframe_ids for r in slam_map.segments], dtype=np.int64).reshape(-1, 2)

    def row(kf_id: int) -> int | None:
        hit = np.flatnonzero((ranges[:, 0] <= kf_id) & (kf_id <= ranges[:, 1]))
        return int(hit[0]) if len(hit) else None
    return row


def topology_graph(slam_map: Map, loops: list[tuple[int, int, int]] = (), min_covisibility: int = 15
                   ) -> tuple[list[dict], list[dict]]:
    """Nodes and edges of the keyframe graph. ``loops`` are ``(query_kf_id, match_kf_id, inliers)``."""
    kfs = sorted((k for k in slam_map.keyframes.values() if not k.bad), key=lambda k: k.id)
    nodes = [{"id": int(k.id), "frame": int(k.frame_index), "T_world_cam": np.asarray(k.T_world_cam)} for k in kfs]
    alive = {k.id for k in kfs}
    edges: list[dict] = []
    row = _segment_rows(slam_map)
    for a, b in zip(kfs[:-1], kfs[1:]):
        if a.segment == b.segment and row(a.id) == row(b.id):
            edges.append({"source": int(a.id), "target": int(b.id), "kind": "odometry", "weight": 1.0})
    for i, links in slam_map.covisibility.items():
        for j, w in links.items():
            if i < j and i in alive and j in alive and w >= min_covisibility:
                edges.append({"source": int(i), "target": int(j), "kind": "covisibility", "weight": float(w)})
    for q, m, inliers in loops:
        if q in alive and m in alive:
            edges.append({"source": int(m), "target": int(q), "kind": "loop", "weight": float(inliers)})
    return nodes, edges


def write_map_outputs(out_dir: str | Path, slam_map: Map, camera: Any = None, database: Any = None,
                      loops_kf: list[tuple[int, int, int]] = (), metadata: dict | None = None,
                      progress: Any = None, plots: bool = True) -> dict:
    """Write ``sparse.ply``, ``topology.json``, ``topology.png`` (with ``plots``) and ``map/`` into
    ``out_dir``. ``progress``: an optional tqdm-like bar (``total``, ``update``), advanced once per output."""
    out = Path(out_dir)
    store = slam_map.points
    n = len(store)
    alive = store.alive[:n]
    X = store.position[:n][alive]
    colors = store.color[:n][alive]
    nodes, edges = topology_graph(slam_map, loops_kf)
    unit = "arbitrary scale" if (metadata or {}).get("sensor") == "mono" else "m"  # a monocular map has no metre
    steps = [("sparse", lambda: export_sparse(out / "sparse.ply", X, colors if colors.any() else None))]
    if nodes:
        steps.append(("topology", lambda: write_topology(out / "topology.json", nodes, edges)))
    if nodes and plots:
        steps.append(("topology_png", lambda: plot_topology(out / "topology.png", nodes, edges, unit=unit)))
    steps.append(("map", lambda: save_map(slam_map, out, database=database, camera=camera, metadata=metadata or {})))
    if progress is not None:
        progress.total = len(steps)
    written = {}
    for name, write in steps:
        written[name] = write()
        if progress is not None:
            progress.update(1)
    log.info("map outputs: %d points, %d keyframes -> %s", int(alive.sum()), len(nodes), out)
    return {k: str(v) for k, v in written.items()}
