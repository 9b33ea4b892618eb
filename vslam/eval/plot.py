"""Evaluation plot: both trajectories from above (aligned estimate vs ground truth, coloured by
ATE) and the ATE along time. Uses matplotlib's Agg canvas directly (no pyplot, no display)."""
from __future__ import annotations

import io
import textwrap
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from vslam.errors import TrajectoryError
from vslam.outputs import atomic_write_bytes

if TYPE_CHECKING:
    from vslam.eval.evaluate import EvalResult

AXIS_NAMES = "xyz"


def top_view_axes(positions: np.ndarray) -> tuple[int, int]:
    """The two axes ``(a, b)``, ``a < b``, with the largest extent of ``(N, 3)`` positions."""
    extent = np.ptp(positions, axis=0)
    a, b = sorted(np.argsort(extent)[-2:].tolist())
    return int(a), int(b)


def _wrap_to_width(text, max_px: float, renderer) -> None:
    """Re-wrap ``text`` (a matplotlib Text) onto as few lines as keep it at most ``max_px`` wide."""
    full = " ".join(text.get_text().split())
    text.set_text(full)
    over = text.get_window_extent(renderer).width / max(max_px, 1.0)
    width = int(len(full) / over) + 1  # characters per line, from the average character's width
    while over > 1.0 and width > 8:
        text.set_text(textwrap.fill(full, width, break_long_words=True))
        over = text.get_window_extent(renderer).width / max(max_px, 1.0)
        width -= 1


def fit_titles(fig, margin_px: float = 6.0) -> None:
    """Lay ``fig`` out tightly with every title inside it: each axes title wrapped to its axes'
    width, the figure's title (``suptitle``) to the figure's, then ``tight_layout`` (twice: the
    wrapped titles are taller, which narrows the axes)."""
    fig.tight_layout()
    for _ in range(2):
        renderer = fig.canvas.get_renderer()
        for ax in fig.axes:
            if ax.get_title():
                _wrap_to_width(ax.title, ax.get_window_extent(renderer).width, renderer)
        if fig._suptitle is not None and fig._suptitle.get_text():
            _wrap_to_width(fig._suptitle, fig.bbox.width - 2 * margin_px, renderer)
        fig.tight_layout()


def plot_evaluation(result: "EvalResult", path: str | Path, title: str | None = None, dpi: int = 110) -> Path:
    """Write a PNG/PDF/SVG (by suffix) of ``result``: top view and ATE vs time.

    Returns the path written.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.collections import LineCollection
    from matplotlib.colors import Normalize
    from matplotlib.figure import Figure

    path = Path(path)
    if not path.parent.is_dir():
        raise TrajectoryError(f"{path}: cannot write the plot, folder {path.parent} does not exist")
    fmt = path.suffix.lower().lstrip(".") or "png"
    if fmt not in FigureCanvasAgg.get_supported_filetypes():
        raise TrajectoryError(f"{path}: cannot write a plot as .{fmt}; use .png, .pdf or .svg")
    gt = result.gt_matched.positions
    est = result.est_aligned.positions
    err = result.ate_errors
    a, b = top_view_axes(gt)

    fig = Figure(figsize=(12, 5.2))
    FigureCanvasAgg(fig)
    ax_top, ax_err = fig.subplots(1, 2, gridspec_kw={"width_ratios": [1.15, 1]})

    ax_top.plot(gt[:, a], gt[:, b], "-", color="0.35", lw=1.2, label="ground truth")
    norm = Normalize(vmin=float(err.min()), vmax=float(max(err.max(), err.min() + 1e-12)))
    segs = np.stack([est[:-1][:, [a, b]], est[1:][:, [a, b]]], axis=1)
    lc = LineCollection(segs, cmap="viridis", norm=norm, lw=1.8)
    lc.set_array(0.5 * (err[:-1] + err[1:]))
    ax_top.add_collection(lc)
    ax_top.plot([], [], color=lc.cmap(0.6), lw=1.8, label=f"estimate ({result.alignment.mode}-aligned)")
    ax_top.plot(gt[0, a], gt[0, b], "ko", ms=5, label="start")
    fig.colorbar(lc, ax=ax_top, label="ATE (m)")
    ax_top.set_xlabel(f"{AXIS_NAMES[a]} (m)")
    ax_top.set_ylabel(f"{AXIS_NAMES[b]} (m)")
    ax_top.set_aspect("equal", adjustable="datalim")
    ax_top.autoscale_view()
    ax_top.legend(loc="best", fontsize=8)
    ax_top.set_title("trajectories (top view)")

    t = result.gt_matched.timestamps - result.gt_matched.timestamps[0]
    ax_err.plot(t, err, "-", color="tab:red", lw=1)
    for value, style, name in ((result.ate.rmse, "--", "rmse"), (result.ate.median, ":", "median")):
        ax_err.axhline(value, color="k", ls=style, lw=1, label=f"{name} {value:.4f} m")
    ax_err.set_xlabel("index" if result.config.by_index else "time (s)")
    ax_err.set_ylabel("ATE (m)")
    ax_err.set_ylim(bottom=0)
    ax_err.legend(loc="best", fontsize=8)
    sim3 = result.alignment.mode == "sim3"
    ax_err.set_title(f"ATE along the path ({result.matched_poses} poses, scale {result.scale:.4f}"
                     + ("; Sim(3)-aligned, the estimate's own scale is arbitrary (monocular)" if sim3 else "") + ")",
                     fontsize=9 if sim3 else None)
    ax_err.grid(alpha=0.3)

    fig.suptitle(title or f"{Path(result.names[0]).name} vs {Path(result.names[1]).name}", fontsize=10)
    fit_titles(fig)  # long titles (a Sim(3) note, long file names) wrapped, never cut off
    buf = io.BytesIO()
    fig.savefig(buf, dpi=dpi, format=fmt)
    atomic_write_bytes(path, buf.getvalue())  # a full disk leaves the previous plot whole
    return path
