"""The ``trajectory.png`` of a run folder: with ground truth, :func:`vslam.eval.plot.plot_evaluation`
(the aligned estimate coloured by its error, and the error along time, as ``vslam demo`` and
``vslam eval --plot`` draw it); without, the estimate from above in the run's own frame (its
axes in metres, or "arbitrary scale" for a monocular run)."""
from __future__ import annotations

import logging
from pathlib import Path

from vslam.errors import VslamError
from vslam.trajectory import Trajectory

log = logging.getLogger(__name__)


def plot_run_trajectory(trajectory: Trajectory, path: str | Path, ground_truth: Trajectory | None = None,
                        align: str = "se3", title: str | None = None, mono: bool = False) -> Path:
    """Write ``path`` (PNG) for ``trajectory`` (``T_world_cam``); returns it.

    ``align`` (``se3``/``sim3``) as the run's ATE. Ground truth that does not overlap the
    estimate is drawn without (the run already warned about it).
    """
    from vslam.eval import evaluate_trajectories
    from vslam.eval.plot import plot_evaluation

    path = Path(path)
    if ground_truth is not None and len(trajectory) >= 3:
        try:
            result = evaluate_trajectories(trajectory, ground_truth, align=align)
        except VslamError as exc:
            log.debug("trajectory.png without ground truth: %s", exc)
        else:
            return plot_evaluation(result, path, title=title)
    return _plot_estimate(trajectory, path, title, "arbitrary scale" if mono else "m")


def _plot_estimate(trajectory: Trajectory, path: Path, title: str | None, unit: str) -> Path:
    """The estimate alone from above, its start marked."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from vslam.eval.plot import AXIS_NAMES, top_view_axes
    from vslam.outputs import atomic_path

    p = trajectory.positions
    a, b = top_view_axes(p) if len(p) >= 2 else (0, 1)
    fig = Figure(figsize=(6.4, 5.2))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    ax.plot(p[:, a], p[:, b], "-", color="#3182bd", lw=1.5, label=f"estimate ({len(p)} poses)")
    if len(p):
        ax.plot(p[0, a], p[0, b], "ko", ms=5, label="start")
    ax.set_xlabel(f"{AXIS_NAMES[a]} [{unit}]")
    ax.set_ylabel(f"{AXIS_NAMES[b]} [{unit}]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    ax.set_title((title + ": " if title else "") + "trajectory from above (no ground truth)", fontsize=10)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=110)
    return path
