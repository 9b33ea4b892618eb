"""The evaluation plot: writes an image with both panels; picks the plane of largest extent."""
from __future__ import annotations

import numpy as np
import pytest

from vslam.errors import TrajectoryError
from vslam.eval import evaluate_trajectories
from vslam.eval.plot import plot_evaluation, top_view_axes
from vslam.trajectory import Trajectory


def test_top_view_axes():
    rng = np.random.default_rng(0)
    p = rng.normal(size=(100, 3)) * [10.0, 0.5, 4.0]  # KITTI-like: x and z wide, y (down) flat
    assert top_view_axes(p) == (0, 2)
    assert top_view_axes(p[:, [1, 0, 2]]) == (1, 2)


def test_plot_writes_png(tmp_path):
    t = np.linspace(0, 10, 120)
    T = np.tile(np.eye(4), (120, 1, 1))
    T[:, :3, 3] = np.stack([np.cos(t), np.sin(t), 0.05 * t], 1)
    gt = Trajectory(t, T)
    noisy = T.copy()
    noisy[:, :3, 3] += np.random.default_rng(1).normal(0, 0.02, (120, 3))
    res = evaluate_trajectories(Trajectory(t, noisy), gt)
    out = plot_evaluation(res, tmp_path / "eval.png")
    data = out.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 20_000
    import matplotlib.image

    img = matplotlib.image.imread(out)
    assert img.shape[1] > 1.8 * img.shape[0]  # two panels side by side
    with pytest.raises(TrajectoryError, match="does not exist"):
        plot_evaluation(res, tmp_path / "missing" / "eval.png")


@pytest.mark.parametrize("align", ["sim3", "se3"])
def test_titles_fit_inside_the_figure(tmp_path, monkeypatch, align):
    """The panels' titles (the long Sim(3) note of a monocular run) and the figure's title (long
    file names) are wrapped to fit: after drawing, each lies inside the figure and its title
    inside its own panel's width."""
    from matplotlib.figure import Figure

    t = np.linspace(0, 10, 120)
    T = np.tile(np.eye(4), (120, 1, 1))
    T[:, :3, 3] = np.stack([np.cos(t), np.sin(t), 0.05 * t], 1)
    est = T.copy()
    est[:, :3, 3] = 2.5 * est[:, :3, 3] + np.random.default_rng(1).normal(0, 0.02, (120, 3))
    res = evaluate_trajectories(Trajectory(t, est), Trajectory(t, T), align=align)
    long_name = "rgbd_dataset_freiburg1_desk_validation_groundtruth_interpolated_for_every_frame_" * 2
    figs = []
    real_savefig = Figure.savefig
    monkeypatch.setattr(Figure, "savefig", lambda self, *a, **kw: (figs.append(self), real_savefig(self, *a, **kw))[1])
    plot_evaluation(res, tmp_path / "eval.png", title=f"{long_name}.txt vs {long_name}_estimate.txt")
    fig = figs[0]
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    inside = fig.bbox.padded(0.5)
    titles = [(ax.title, ax) for ax in fig.axes if ax.get_title()] + [(fig._suptitle, None)]
    assert len(titles) == 3 and ("Sim(3)" in titles[1][0].get_text()) == (align == "sim3")
    for text, ax in titles:
        box = text.get_window_extent(renderer)
        assert box.width > 0 and inside.contains(box.x0, box.y0) and inside.contains(box.x1, box.y1), text.get_text()
        if ax is not None:
            assert box.width <= ax.get_window_extent(renderer).width + 1
    # no two titles overlap, and the wrapped text keeps every character (a long name is broken, not cut)
    boxes = [t.get_window_extent(renderer) for t, _ in titles]
    assert not any(boxes[i].overlaps(boxes[j]) for i in range(3) for j in range(i + 1, 3))
    assert "".join(titles[2][0].get_text().split()) == f"{long_name}.txtvs{long_name}_estimate.txt"
    assert "\n" in titles[2][0].get_text()
