"""The segment table of a map: where each group of keyframes came from and how it was placed.

A keyframe's ``segment`` (:class:`vslam.map.keyframe.KeyFrame`) is the connected piece of the map it
belongs to: one coordinate frame, covisibility and loop closing within it. A map built by one run
has one segment per tracking re-initialization (0, 1, ...). Merging maps (:mod:`vslam.merge`) joins
the pieces of another map into a segment of this one; the table records, for every piece, its
origin and the similarity that placed it (map format version 2, ``map.json`` ``segments``):

* ``segment``: the ``KeyFrame.segment`` its keyframes carry now (pieces with the same value were joined);
* ``source``: the map it was built in (``""``: this map's own run);
* ``source_segment``: its segment id in that map;
* ``keyframe_ids``: ``[first, last]``, the id range its keyframes occupy here;
* ``S_segment_source``: ``(4, 4)`` Sim(3) ``[s R, t; 0, 1]`` mapping the source's world into this
  map's world (identity for the map's own pieces; ``s != 1`` only for monocular merges).

A map built by one run records no rows (``Map.segments == []``, saved as ``[]``): its table is
:func:`default_segments`, one row per distinct ``KeyFrame.segment``, from its own run,
untransformed (:func:`segment_table`). A version-1 map (written before segments were recorded)
loads the same way.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from vslam.errors import MapFormatError
from vslam.map.map import Map

SEGMENT_KEYS = ("segment", "source", "source_segment", "keyframe_ids", "S_segment_source")


@dataclass(eq=False)
class SegmentRecord:
    """One row of the segment table (see the module docstring); equal when their JSON rows are."""

    segment: int
    source: str
    source_segment: int
    keyframe_ids: tuple[int, int]
    S_segment_source: np.ndarray = field(default_factory=lambda: np.eye(4))

    def __eq__(self, other: object) -> bool:
        return isinstance(other, SegmentRecord) and self.to_json() == other.to_json()

    __hash__ = None  # type: ignore[assignment]  # mutable

    @property
    def scale(self) -> float:
        return float(np.cbrt(np.linalg.det(self.S_segment_source[:3, :3])))

    def to_json(self) -> dict:
        return {"segment": int(self.segment), "source": str(self.source), "source_segment": int(self.source_segment),
                "keyframe_ids": [int(self.keyframe_ids[0]), int(self.keyframe_ids[1])],
                "S_segment_source": [[float(x) for x in row] for row in np.asarray(self.S_segment_source)]}

    @classmethod
    def from_json(cls, where: str, data: object) -> "SegmentRecord":
        """Parse one row; :class:`MapFormatError` naming ``where`` when it is malformed."""
        if not isinstance(data, dict) or set(data) != set(SEGMENT_KEYS):
            raise MapFormatError(f"{where}: malformed segment entry {data!r} (keys {list(SEGMENT_KEYS)} needed)")
        try:
            S = np.asarray(data["S_segment_source"], dtype=float)
            ids = data["keyframe_ids"]
            ok = (S.shape == (4, 4) and np.all(np.isfinite(S)) and np.allclose(S[3], [0, 0, 0, 1])
                  and np.linalg.det(S[:3, :3]) > 0 and isinstance(ids, list) and len(ids) == 2
                  and all(isinstance(v, int) and not isinstance(v, bool) for v in
                          (data["segment"], data["source_segment"], *ids))
                  and isinstance(data["source"], str))
        except (TypeError, ValueError):
            ok = False
        if not ok:
            raise MapFormatError(f"{where}: malformed segment entry {data!r}")
        return cls(data["segment"], data["source"], data["source_segment"], (ids[0], ids[1]), S)


def default_segments(slam_map: Map) -> list[SegmentRecord]:
    """One row per distinct ``KeyFrame.segment`` of ``slam_map``: its own run, untransformed."""
    rows: dict[int, list[int]] = {}
    for kf in slam_map.keyframes.values():
        rows.setdefault(int(kf.segment), []).append(int(kf.id))
    return [SegmentRecord(s, "", s, (min(ids), max(ids))) for s, ids in sorted(rows.items())]


def segment_table(slam_map: Map) -> list[SegmentRecord]:
    """The map's recorded table (``Map.segments``), or :func:`default_segments` when none is recorded."""
    return list(slam_map.segments) if slam_map.segments else default_segments(slam_map)


def segments_to_json(slam_map: Map) -> list[dict]:
    """The recorded rows (``[]`` for a map built by one run: its table is :func:`default_segments`)."""
    return [r.to_json() for r in slam_map.segments]


def segments_from_json(where: str, data: object) -> list[SegmentRecord]:
    if not isinstance(data, list):
        raise MapFormatError(f"{where}: 'segments' must be a list, got {type(data).__name__}")
    return [SegmentRecord.from_json(where, row) for row in data]
