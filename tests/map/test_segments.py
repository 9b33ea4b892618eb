"""The segment table (map format 2), loading version-1 maps, and appending a map under a Sim(3)."""
from __future__ import annotations

import copy
import json
from pathlib import Path

import numpy as np
import pytest

from vslam.errors import MapFormatError
from vslam.geometry.lie import make_T
from vslam.map.append import append_map
from vslam.map.io import load_map, save_map
from vslam.map.segments import SegmentRecord, default_segments, segment_table
from tests.map._builders import assert_maps_equal, random_database, random_map, random_rotation


def _as_version_1(root: Path) -> None:
    """Rewrite a saved map.json exactly as the version-1 writer (main before the segment table) made
    it: the same keys and files, ``version`` 1, no ``segments``."""
    manifest = json.loads((root / "map.json").read_text())
    manifest["version"] = 1
    del manifest["segments"]
    (root / "map.json").write_text(json.dumps(manifest, indent=1) + "\n")


def test_version_1_map_loads_as_one_segment_per_keyframe_segment(tmp_path: Path) -> None:
    m = random_map(3, n_keyframes=6)
    for kf in list(m.keyframes.values())[4:]:
        kf.segment = 1  # a re-initialization after tracking was lost
    root = save_map(m, tmp_path, database=random_database(3, list(m.keyframes)))
    _as_version_1(root)
    loaded, db, _, _ = load_map(tmp_path)
    assert_maps_equal(m, loaded)
    assert loaded.segments == [] and sorted(db.keyframe_ids) == sorted(m.keyframes)
    table = segment_table(loaded)
    ids = sorted(m.keyframes)
    assert [(r.segment, r.source, r.source_segment, r.keyframe_ids) for r in table] == \
        [(0, "", 0, (ids[0], ids[3])), (1, "", 1, (ids[4], ids[5]))]
    assert all(np.array_equal(r.S_segment_source, np.eye(4)) and r.scale == 1.0 for r in table)
    # re-saving writes version 2 with an empty table ([]: the default, one run's own segments)
    save_map(loaded, tmp_path / "v2")
    manifest = json.loads((tmp_path / "v2" / "map" / "map.json").read_text())
    assert manifest["version"] == 2 and manifest["segments"] == []


def _sim3(seed: int, scale: float) -> np.ndarray:
    rng = np.random.default_rng(seed)
    S = make_T(random_rotation(rng), rng.normal(size=3))
    S[:3, :3] *= scale
    return S


@pytest.mark.parametrize("scale", [1.0, 2.5])
def test_append_map_moves_everything_by_the_similarity(tmp_path: Path, scale: float) -> None:
    a, b = random_map(1, n_keyframes=5), random_map(2, n_keyframes=4)
    b_before = copy.deepcopy(b)
    n_a_pts, n_a_kf = len(a.points), a.next_keyframe_id()
    S = _sim3(7, scale)
    res = append_map(a, b, S, source="runs/b", segment_map={0: 0})
    assert (res.kf_offset, res.point_offset) == (n_a_kf, n_a_pts)
    assert_maps_equal(b, b_before)  # the source is not modified
    assert len(a.keyframes) == 9 and len(a.points) == n_a_pts + len(b.points)
    # points: X' = s R X + t, distance ranges scaled, keyframe references shifted
    X = b.points.position[: len(b.points)]
    got = a.points.position[n_a_pts: n_a_pts + len(b.points)]
    np.testing.assert_allclose(got, X @ S[:3, :3].T + S[:3, 3], atol=1e-12)
    np.testing.assert_allclose(a.points.max_distance[n_a_pts: len(a.points)], scale * b.points.max_distance[: len(b.points)])
    assert np.array_equal(a.points.first_kf[n_a_pts: len(a.points)], b.points.first_kf[: len(b.points)] + n_a_kf)
    for kid, kf in b.keyframes.items():
        new = a.keyframes[kid + n_a_kf]
        # the camera stays rigid; its centre and every point it observes move together
        np.testing.assert_allclose(new.T_world_cam[:3, :3] @ new.T_world_cam[:3, :3].T, np.eye(3), atol=1e-12)
        np.testing.assert_allclose(new.centre, S[:3, :3] @ kf.centre + S[:3, 3], atol=1e-12)
        obs = kf.point_ids >= 0
        assert np.array_equal(new.point_ids[obs], kf.point_ids[obs] + n_a_pts) and np.all(new.point_ids[~obs] == -1)
        Xc_old = (kf.T_cam_world @ np.c_[X[kf.point_ids[obs]], np.ones(obs.sum())].T)[:3]
        Xc_new = (new.T_cam_world @ np.c_[a.points.position[new.point_ids[obs]], np.ones(obs.sum())].T)[:3]
        np.testing.assert_allclose(Xc_new, scale * Xc_old, atol=1e-9)
        assert new.segment == 0
        assert a.covisibility[kid + n_a_kf] == {j + n_a_kf: w for j, w in b.covisibility[kid].items()}
    table = a.segments
    assert [(r.segment, r.source, r.keyframe_ids) for r in table] == \
        [(0, "", (0, 3)), (1, "", (4, 4)), (0, "runs/b", (n_a_kf, n_a_kf + 3))]  # A: segments 0, 1 (k // 4)
    assert table[2].scale == pytest.approx(scale)
    # the table survives a save / load (format version 2)
    save_map(a, tmp_path)
    loaded, _, _, _ = load_map(tmp_path)
    assert_maps_equal(a, loaded)
    assert [r.to_json() for r in loaded.segments] == [r.to_json() for r in table]


def test_unjoined_segments_get_fresh_ids() -> None:
    a, b = random_map(1, n_keyframes=3), random_map(2, n_keyframes=3)
    list(b.keyframes.values())[-1].segment = 1
    res = append_map(a, b, np.eye(4))
    assert res.segment_map == {0: 1, 1: 2}
    assert [r.segment for r in segment_table(a)] == [0, 1, 2]


def test_malformed_segment_table_is_refused(tmp_path: Path) -> None:
    a = random_map(1, n_keyframes=3)
    a.segments = default_segments(a)
    root = save_map(a, tmp_path)
    manifest = json.loads((root / "map.json").read_text())
    manifest["segments"][0]["S_segment_source"] = [[1, 0, 0, 0]] * 4
    (root / "map.json").write_text(json.dumps(manifest))
    with pytest.raises(MapFormatError, match="map.json: malformed segment entry"):
        load_map(tmp_path)
    manifest["segments"] = {"0": 1}
    (root / "map.json").write_text(json.dumps(manifest))
    with pytest.raises(MapFormatError, match="'segments' must be a list"):
        load_map(tmp_path)


def test_segment_record_json_round_trip() -> None:
    r = SegmentRecord(2, "x", 0, (10, 20), _sim3(3, 0.5))
    back = SegmentRecord.from_json("t", json.loads(json.dumps(r.to_json())))
    assert back.to_json() == r.to_json() and back.scale == pytest.approx(0.5)
