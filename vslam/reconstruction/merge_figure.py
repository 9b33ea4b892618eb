"""``merge.png`` of ``vslam merge``: both maps' keyframes from above in the merged (A's) frame,
coloured by the map they came from, the seam (each B keyframe matched to an A keyframe) marked,
and the alignment's inlier count and residual in the title.

Example::

    plot_merge("AB/merge.png", merged_map, kf_offset=120, seam=[[130, 12, 85]],
               alignment={"inliers": 412, "residual": 0.011}, unit="m")
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Iterable

import numpy as np

A_COLOUR, B_COLOUR, SEAM_COLOUR = "#3182bd", "#e6550d", "#e31a1c"


def _top_axes(T_world_cam: np.ndarray) -> tuple[int, int]:
    """The two world axes of a view from above: the cameras' mean image-down axis is the vertical
    when one world axis dominates it, else the two axes of largest extent."""
    from vslam.eval.plot import top_view_axes

    down = np.mean(T_world_cam[:, :3, 1], axis=0)
    if np.max(np.abs(down)) >= 0.5:
        vertical = int(np.argmax(np.abs(down)))
        a, b = (i for i in range(3) if i != vertical)
        return a, b
    return top_view_axes(T_world_cam[:, :3, 3]) if len(T_world_cam) >= 2 else (0, 1)


def plot_merge(path: str | Path, slam_map: Any, kf_offset: int, seam: Iterable[Iterable[int]],
               alignment: dict, unit: str = "m") -> Path:
    """Write ``path`` (PNG) of :func:`draw_merge`; returns it."""
    from vslam.outputs import atomic_path

    fig = draw_merge(slam_map, kf_offset, seam, alignment, unit)
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=110)
    return path


def draw_merge(slam_map: Any, kf_offset: int, seam: Iterable[Iterable[int]], alignment: dict, unit: str = "m"):
    """The figure: the good keyframes of ``slam_map`` with id ``< kf_offset`` (map A) and ``>=
    kf_offset`` (map B, appended), by timestamp; ``seam`` rows ``[b_kf, a_kf, inliers]`` (merged ids)
    drawn as links; ``alignment`` ``{"inliers", "residual"}`` in the title."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    kfs = sorted((k for k in slam_map.keyframes.values() if not k.bad), key=lambda k: (k.timestamp, k.id))
    T = np.stack([k.T_world_cam for k in kfs]) if kfs else np.zeros((0, 4, 4))
    a, b = _top_axes(T) if len(T) else (0, 1)
    fig = Figure(figsize=(6.4, 5.4))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    for name, colour, sel in (("A", A_COLOUR, lambda k: k.id < kf_offset), ("B", B_COLOUR, lambda k: k.id >= kf_offset)):
        p = np.array([k.T_world_cam[:3, 3] for k in kfs if sel(k)]).reshape(-1, 3)
        ax.plot(p[:, a], p[:, b], ".-", color=colour, lw=0.8, ms=4, label=f"map {name}: {len(p)} keyframes")
    pos = {k.id: k.T_world_cam[:3, 3] for k in kfs}
    links = [(pos[int(r[0])], pos[int(r[1])]) for r in seam if int(r[0]) in pos and int(r[1]) in pos]
    for i, (pb, pa) in enumerate(links):
        ax.plot([pb[a], pa[a]], [pb[b], pa[b]], "-", color=SEAM_COLOUR, lw=1.6,
                label=f"seam: {len(links)} matched keyframes" if i == 0 else None)
        ax.plot([pb[a], pa[a]], [pb[b], pa[b]], "o", mfc="none", color=SEAM_COLOUR, ms=7)
    ax.set_xlabel(f"{'xyz'[a]} [{unit}]")
    ax.set_ylabel(f"{'xyz'[b]} [{unit}]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    residual = alignment.get("residual")
    res_text = f"residual {residual:.4f} {unit}" if isinstance(residual, (int, float)) else "residual -"
    ax.set_title(f"merged map (A's frame): alignment {alignment.get('inliers', '-')} inliers, {res_text}", fontsize=10)
    fig.tight_layout()
    return fig
