"""`vslam merge` on real sequences (issue #18): overlapping 7-Scenes slices merged into one map
that localizes later frames; KITTI 07 slices that do not overlap give a one-line error.

The full-size cases of the issue (7-Scenes 0-499 + 500-999, TUM cabinet and KITTI 07 halves) are
measured in benchmarks/RESULTS.md ("Map merging"); here slices keep the suite fast."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from vslam.api import run_path
from vslam.cli import main
from vslam.datasets import open_dataset
from vslam.eval.evaluate import evaluate_trajectories
from vslam.localize import localize_path
from vslam.map.io import load_map
from vslam.map.segments import segment_table
from vslam.trajectory import read_tum


def _ate(folder: Path, data: Path, align: str = "se3") -> float:
    r = evaluate_trajectories(read_tum(folder / "keyframes.txt"), open_dataset(data).ground_truth(), align=align)
    return float(r.ate.rmse)


@pytest.fixture(scope="module")
def kitchen(shared_data: Path, tmp_path_factory) -> dict:
    """7-Scenes redkitchen frames 0-299 and 250-549 mapped separately, then merged by the CLI."""
    data = shared_data / "7scenes_redkitchen"
    root = tmp_path_factory.mktemp("merge")
    run_path(data, root / "A", sensor="rgbd", max_frames=300)
    run_path(data, root / "B", sensor="rgbd", start_frame=250, max_frames=300)
    rc = main(["merge", str(root / "A"), str(root / "B"), "-o", str(root / "AB")])
    return {"data": data, "root": root, "rc": rc}


def test_merged_keyframes_share_one_frame(kitchen: dict) -> None:
    root, data = kitchen["root"], kitchen["data"]
    assert kitchen["rc"] == 0
    for name in ("map/map.json", "keyframes.txt", "sparse.ply", "stats.json", "config.yaml", "merge.png"):
        assert (root / "AB" / name).is_file(), name
    stats = json.loads((root / "AB" / "stats.json").read_text())
    n_a, n_b = stats["keyframes_a"], stats["keyframes_b"]
    assert stats["seam_keyframes"] >= 10 and stats["scale"] == 1.0
    # the alignment's inliers (of the seam's 3D-3D correspondences) and their RMS residual, in metres
    assert 100 <= stats["alignment_inliers"] <= stats["alignment_correspondences"]
    assert 0.001 < stats["alignment_residual"] < 0.05
    assert stats["figure"] == str(root / "AB" / "merge.png") and (root / "AB" / "merge.png").stat().st_size > 20_000
    # one SE(3) alignment of all merged keyframes to the ground truth: as good as the separate maps
    ate = _ate(root / "AB", data)
    assert 0.025 < ate < 0.045  # measured 0.036 (A alone 0.023, B alone 0.038)
    # B moved into A's frame: A's keyframes keep their poses up to the welding BA's few millimetres
    kf_a = read_tum(root / "A" / "keyframes.txt")
    kf_ab = read_tum(root / "AB" / "keyframes.txt")
    common = np.isin(kf_ab.timestamps, kf_a.timestamps)
    assert common.sum() == len(kf_a)
    moved = np.linalg.norm(kf_ab.T_world_cam[common, :3, 3] - kf_a.T_world_cam[:, :3, 3], axis=1)
    assert np.median(moved) < 0.02
    # the saved map: one segment made of two sources, B's with its transform
    merged, db, _, meta = load_map(root / "AB")
    table = segment_table(merged)
    assert [(r.segment, r.source) for r in table] == [(0, ""), (0, str((root / "B").resolve()))]
    np.testing.assert_allclose(table[1].S_segment_source, np.asarray(stats["S_a_b"]), atol=1e-6)
    assert len(merged.keyframes) == n_a + n_b and len(db) == n_a + n_b
    assert {k.segment for k in merged.keyframes.values()} == {0}
    assert meta["merged"][0]["b"] == str((root / "B").resolve())


def test_later_frames_localize_in_the_merged_map(kitchen: dict, tmp_path: Path) -> None:
    """Frames only B saw (500-549) localize in the merged map, in A's frame."""
    res = localize_path(kitchen["root"] / "AB", kitchen["data"], tmp_path / "loc", start_frame=500, max_frames=50)
    s = res.stats
    assert s["localized_ratio"] >= 0.9 and 0.004 < s["ate_rmse"] < 0.025  # measured 100 %, 0.011 m


def test_maps_that_do_not_overlap_are_an_error(shared_data: Path, tmp_path: Path, capsys) -> None:
    data = shared_data / "kitti_odometry" / "sequences" / "07"
    run_path(data, tmp_path / "A", sensor="mono", max_frames=25)
    run_path(data, tmp_path / "B", sensor="mono", start_frame=135, max_frames=25)
    rc = main(["merge", str(tmp_path / "A"), str(tmp_path / "B"), "-o", str(tmp_path / "AB")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and err.startswith("vslam merge: error: the maps do not overlap:") and "\n" not in err
    assert not (tmp_path / "AB" / "map").exists()


def test_missing_map_is_an_error(tmp_path: Path, capsys) -> None:
    rc = main(["merge", str(tmp_path / "nope"), str(tmp_path / "nope2"), "-o", str(tmp_path / "AB")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "no such map folder" in err


def test_merge_figure_colours_the_maps_and_marks_the_seam() -> None:
    """``merge.png``'s figure: A's and B's keyframes as two lines of their own colour, one link per
    seam match between the matched keyframes, the alignment in the title."""
    from types import SimpleNamespace

    from vslam.reconstruction.merge_figure import A_COLOUR, B_COLOUR, SEAM_COLOUR, draw_merge

    def kf(i: int, x: float, y: float) -> SimpleNamespace:
        T = np.eye(4)
        T[:3, :3] = [[1, 0, 0], [0, 0, 1], [0, -1, 0]]  # camera y (image down) along world -z: z is vertical
        T[:3, 3] = [x, y, 0.0]
        return SimpleNamespace(id=i, timestamp=float(i), T_world_cam=T, bad=False)

    kfs = [kf(i, i * 0.1, 0.0) for i in range(6)] + [kf(10 + i, 0.3 + 0.1 * i, 0.05) for i in range(5)]
    merged = SimpleNamespace(keyframes={k.id: k for k in kfs})
    fig = draw_merge(merged, 10, [[10, 3, 120], [11, 4, 90]], {"inliers": 412, "residual": 0.011})
    ax = fig.axes[0]
    a_line, b_line = ax.lines[0], ax.lines[1]
    assert (a_line.get_color(), len(a_line.get_xdata())) == (A_COLOUR, 6)
    assert (b_line.get_color(), len(b_line.get_xdata())) == (B_COLOUR, 5)
    seam = [l for l in ax.lines if l.get_color() == SEAM_COLOUR and l.get_linestyle() == "-"]
    assert len(seam) == 2
    np.testing.assert_allclose(np.column_stack([seam[0].get_xdata(), seam[0].get_ydata()]), [[0.3, 0.05], [0.3, 0.0]])
    assert ax.get_title() == "merged map (A's frame): alignment 412 inliers, residual 0.0110 m"
    labels = ax.get_legend_handles_labels()[1]
    assert labels == ["map A: 6 keyframes", "map B: 5 keyframes", "seam: 2 matched keyframes"]
