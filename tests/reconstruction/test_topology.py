"""Topological map: JSON round trip, validation, and the top-view plot."""
from __future__ import annotations

import json

import numpy as np
import pytest

from vslam.errors import MapFormatError
from vslam.reconstruction.topology import (
    nodes_from_poses, normalize, plane_axes, plot_topology, read_topology, write_topology,
)


def _loop_graph(n: int = 24, seed: int = 0):
    """Keyframes on a circle of radius 2 m in the world x-z plane (camera y down), a loop 0 <-> n-1."""
    rng = np.random.default_rng(seed)
    ang = np.linspace(0, 2 * np.pi, n, endpoint=False)
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, 0, 3], T[:, 2, 3] = 2 * np.cos(ang), 2 * np.sin(ang)
    T[:, 1, 3] = rng.normal(scale=0.02, size=n)
    c, s = np.cos(ang), np.sin(ang)
    T[:, 0, 0], T[:, 0, 2], T[:, 2, 0], T[:, 2, 2] = c, s, -s, c
    nodes = nodes_from_poses(T, frames=np.arange(n) * 5, ids=np.arange(n) + 100)
    edges = [{"source": 100 + i, "target": 101 + i, "kind": "odometry", "weight": 1.0} for i in range(n - 1)]
    edges += [{"source": 100 + i, "target": 100 + (i + 2) % n, "kind": "covisibility", "weight": float(w)}
              for i, w in zip(range(n), rng.integers(15, 300, n))]
    edges.append({"source": 100 + n - 1, "target": 100, "kind": "loop", "weight": 42.5})
    return nodes, edges


def test_json_round_trip_is_exact(tmp_path):
    nodes, edges = _loop_graph()
    path = write_topology(tmp_path / "topology.json", nodes, edges)
    doc = json.loads(path.read_text())
    assert doc["version"] == 1 and len(doc["nodes"]) == 24 and len(doc["edges"]) == 24 + 23 + 1
    assert set(doc["nodes"][0]) == {"id", "frame", "T_world_cam"}
    assert set(doc["edges"][0]) == {"source", "target", "kind", "weight"}
    got_nodes, got_edges = read_topology(path)
    assert [n["id"] for n in got_nodes] == [n["id"] for n in nodes]
    assert [n["frame"] for n in got_nodes] == [n["frame"] for n in nodes]
    for a, b in zip(got_nodes, nodes):
        np.testing.assert_array_equal(a["T_world_cam"], b["T_world_cam"])  # bit-exact floats
    assert got_edges == edges


def test_objects_with_attributes_are_accepted(tmp_path):
    from types import SimpleNamespace as NS

    nodes = [NS(id=1, frame=10, T_world_cam=np.eye(4)), NS(id=2, frame=20, T_world_cam=np.eye(4))]
    edges = [NS(source=1, target=2, kind="covisibility", weight=37)]
    got_nodes, got_edges = read_topology(write_topology(tmp_path / "t.json", nodes, edges))
    assert got_edges == [{"source": 1, "target": 2, "kind": "covisibility", "weight": 37.0}]
    assert got_nodes[1]["frame"] == 20


def test_invalid_graphs_are_rejected(tmp_path):
    nodes, _ = _loop_graph(4)
    with pytest.raises(MapFormatError, match="kind 'teleport'"):
        normalize(nodes, [{"source": 100, "target": 101, "kind": "teleport"}])
    with pytest.raises(MapFormatError, match="not in the node list"):
        normalize(nodes, [{"source": 100, "target": 7, "kind": "loop"}])
    with pytest.raises(MapFormatError, match="duplicate node id 100"):
        normalize(nodes + nodes[:1], [])
    bad = [{"id": 1, "frame": 1, "T_world_cam": np.eye(3)}]
    with pytest.raises(MapFormatError, match="4x4"):
        normalize(bad, [])
    (tmp_path / "broken.json").write_text('{"nodes": [')
    with pytest.raises(MapFormatError, match="not valid JSON"):
        read_topology(tmp_path / "broken.json")
    (tmp_path / "v2.json").write_text('{"version": 2, "nodes": [], "edges": []}')
    with pytest.raises(MapFormatError, match="version 2"):
        read_topology(tmp_path / "v2.json")


def test_plane_of_the_two_largest_extents():
    nodes, _ = _loop_graph()
    centres = np.array([n["T_world_cam"][:3, 3] for n in nodes])
    assert plane_axes(centres) == (0, 2)  # the circle lies in x-z; y only jitters
    assert plane_axes(np.array([[0, 0, 0], [1, 5, 0.1]])) == (0, 1)


def test_plot_is_written(tmp_path):
    nodes, edges = _loop_graph()
    png = plot_topology(tmp_path / "topology.png", nodes, edges, title="loop test")
    data = png.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 20_000
    import matplotlib.image as mpimg

    img = mpimg.imread(png)
    assert img.shape[0] > 400 and img.shape[1] > 500
    red = (img[..., 0] > 0.7) & (img[..., 1] < 0.3) & (img[..., 2] < 0.3)  # the loop edge is drawn in red
    assert red.sum() > 50
