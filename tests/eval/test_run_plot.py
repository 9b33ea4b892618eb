"""``trajectory.png`` of `vslam run` (issue #25, item 10): the evaluation plot (estimate coloured by
its error against ground truth) when there is ground truth, the estimate alone otherwise, in
"arbitrary scale" for a monocular run."""
from __future__ import annotations

import json

import numpy as np
import pytest
from matplotlib.figure import Figure

from vslam.cli import main
from vslam.eval.run_plot import plot_run_trajectory
from vslam.trajectory import Trajectory


@pytest.fixture
def drawn(monkeypatch):
    """Every figure saved, as (x labels, y labels, titles) of its axes; the file is still written."""
    out = []
    save = Figure.savefig

    def keep(fig, *args, **kwargs):
        out.append(([ax.get_xlabel() for ax in fig.axes], [ax.get_ylabel() for ax in fig.axes],
                    [ax.get_title() for ax in fig.axes]))
        return save(fig, *args, **kwargs)

    monkeypatch.setattr(Figure, "savefig", keep)
    return out


def _circle(n: int = 30, scale: float = 1.0) -> Trajectory:
    t = np.arange(n) * 0.1
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, 0, 3] = scale * np.cos(t)
    T[:, 1, 3] = scale * np.sin(t)
    return Trajectory(t, T)


def test_with_ground_truth_the_error_is_drawn(tmp_path, drawn):
    gt = _circle()
    est = _circle(scale=0.5)  # a monocular run: half the size, Sim(3) puts it on the ground truth
    path = plot_run_trajectory(est, tmp_path / "t.png", gt, align="sim3", mono=True)
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    (xlabels, ylabels, titles), = drawn
    assert "x (m)" in xlabels and "ATE (m)" in ylabels  # aligned to the ground truth: metres
    assert any(t.startswith("ATE along the path") for t in titles)


def test_without_ground_truth_the_estimate_alone(tmp_path, drawn):
    plot_run_trajectory(_circle(), tmp_path / "mono.png", None, mono=True)
    plot_run_trajectory(_circle(), tmp_path / "rgbd.png", None)
    # ground truth that covers none of the estimate's times: drawn without it
    far = Trajectory(_circle().timestamps + 100.0, _circle().T_world_cam)
    plot_run_trajectory(_circle(), tmp_path / "far.png", far)
    assert [d[0] for d in drawn] == [["x [arbitrary scale]"], ["x [m]"], ["x [m]"]]
    assert all("no ground truth" in d[2][0] for d in drawn)
    assert all((tmp_path / f).is_file() for f in ("mono.png", "rgbd.png", "far.png"))


def test_vslam_run_writes_trajectory_png(shared_data, tmp_path, capsys, drawn):
    seq = shared_data / "tum_rgbd_freiburg1_desk_9frames"
    assert main(["run", str(seq), "-o", str(tmp_path / "run"), "--no-progress"]) == 0
    png = tmp_path / "run" / "trajectory.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert any("ATE (m)" in ylabels for _, ylabels, _ in drawn)
    assert json.loads((tmp_path / "run" / "stats.json").read_text())["matched_poses"] == 9
