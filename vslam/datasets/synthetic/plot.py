"""Top-down plot of a synthetic sequence: the room, its furniture and the ground-truth camera path."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from vslam.datasets.synthetic.scene import SceneSpec


def plot_ground_truth_topdown(
    T_world_cam: np.ndarray, out_png: str | Path, spec: SceneSpec = SceneSpec(), title: str = "ground truth"
) -> Path:
    """Save a top view (world x-y, z up) of the path, its heading every few frames, and the room."""
    from matplotlib.figure import Figure  # no pyplot: no global backend state, Agg canvas
    from matplotlib.patches import Rectangle

    T = np.asarray(T_world_cam).reshape(-1, 4, 4)
    pos = T[:, :3, 3]
    fig = Figure(figsize=(7, 5))
    ax = fig.subplots()
    lo, hi = spec.room_lo, spec.room_hi
    ax.add_patch(Rectangle(lo[:2], hi[0] - lo[0], hi[1] - lo[1], fill=False, lw=2, color="k"))
    for box in spec.boxes:
        ax.add_patch(Rectangle(box.lo[:2], box.hi[0] - box.lo[0], box.hi[1] - box.lo[1], color="0.75", ec="0.4"))
    ax.plot(pos[:, 0], pos[:, 1], "-", color="tab:blue", lw=1.5, label="camera path")
    step = max(len(T) // 24, 1)
    fwd = T[::step, :3, 2]
    ax.quiver(pos[::step, 0], pos[::step, 1], fwd[:, 0], fwd[:, 1], color="tab:orange", width=0.004,
              scale=12, label="viewing direction")
    ax.plot(*pos[0, :2], "go", label="start")
    ax.plot(*pos[-1, :2], "rx", label="end")
    ax.set_aspect("equal")
    ax.set_xlim(lo[0] - 0.3, hi[0] + 0.3)
    ax.set_ylim(lo[1] - 0.3, hi[1] + 0.3)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(f"{title} ({len(T)} frames, top view)")
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)
    out_png = Path(out_png)
    fig.savefig(out_png, dpi=110, bbox_inches="tight")
    return out_png
