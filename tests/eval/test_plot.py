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
