"""The map files of a run (sparse.ply, topology, map/) and the progress they report."""
from __future__ import annotations

import importlib.util
from pathlib import Path

from vslam.map.io import load_map
from vslam.reconstruction.map_outputs import write_map_outputs

_spec = importlib.util.spec_from_file_location("_builders", Path(__file__).parents[1] / "map" / "_builders.py")
_builders = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_builders)


class SpyBar:
    """A tqdm stand-in recording what the writer reports."""

    def __init__(self) -> None:
        self.total = None
        self.n = 0

    def update(self, k: int = 1) -> None:
        self.n += k


def test_every_output_is_written_and_counted(tmp_path):
    slam_map = _builders.random_map(3, n_keyframes=6, n_keypoints=120)
    bar = SpyBar()
    written = write_map_outputs(tmp_path, slam_map, progress=bar)
    assert set(written) == {"sparse", "topology", "topology_png", "map"}
    assert bar.total == 4 and bar.n == 4  # one step per output, all done
    assert all(Path(p).exists() for p in written.values())
    loaded, _db, _cam, _meta = load_map(tmp_path)
    assert sorted(loaded.keyframes) == sorted(slam_map.keyframes)


def test_odometry_edges_stay_within_each_session_of_a_merged_map():
    """A merged map (``vslam merge`` / ``vslam map``) welds its sessions into one segment but keeps a
    segment-table row each: consecutive keyframe ids across two rows are no odometry edge."""
    import numpy as np

    from vslam.map.segments import SegmentRecord
    from vslam.reconstruction.map_outputs import topology_graph

    slam_map = _builders.random_map(3, n_keyframes=6, n_keypoints=120)
    ids = sorted(slam_map.keyframes)
    for k in ids:
        slam_map.keyframes[k].segment = 0
    nodes, edges = topology_graph(slam_map)
    assert sum(e["kind"] == "odometry" for e in edges) == 5  # one run: every consecutive pair
    slam_map.segments = [SegmentRecord(0, "", 0, (ids[0], ids[2])),
                         SegmentRecord(0, "b", 0, (ids[3], ids[5]), np.eye(4))]
    nodes, edges = topology_graph(slam_map)
    odo = {(e["source"], e["target"]) for e in edges if e["kind"] == "odometry"}
    assert odo == {(ids[0], ids[1]), (ids[1], ids[2]), (ids[3], ids[4]), (ids[4], ids[5])}
