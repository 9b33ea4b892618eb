"""Every trajectory of one benchmark run in one plot, as ``evo_traj`` draws them (issue 25).

For each run name with more than one trajectory (several repeats, and/or a baseline's rows
``<run>@<system>``), ``traj_<run>.png`` in the benchmark folder draws, from above, every
successful repeat's ``trajectory.txt`` (vslam in blues, each baseline in its own colours) and the
ground truth of the sequence when it has one. Each trajectory is aligned to the ground truth as
its ATE is (:func:`vslam.eval.evaluate_trajectories`: SE(3), Sim(3) for a monocular run) and its
ATE is in the legend; without ground truth every trajectory is aligned (the same way) to the
first vslam repeat, as ``evo_traj --ref`` does, so repeats that differ only by their start frame
coincide. A trajectory that cannot be aligned is drawn as it is, said in the legend. With ground
truth, a second panel draws each aligned trajectory's position error over time (the per-pose errors
of its ATE): peaks that vslam and the baseline share at the same frames are an error both make (see
:mod:`vslam.bench.common_frames`), not one system's.

The ground truth is the sequence's own (:func:`vslam.datasets.ground_truth.resolve_ground_truth`,
what ``vslam run`` evaluates against), else a ``groundtruth.txt`` in one of the run folders (the
bench's fake runner writes one). Files are written atomically
(:func:`vslam.outputs.atomic_write_bytes`) and listed in ``results.md``
(:func:`overlays_markdown`).

Example::

    files = write_overlays(rows, "bench_out", meta)   # {"traj_desk": Path("bench_out/traj_desk.png")}
"""
from __future__ import annotations

import io
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from vslam.errors import VslamError
from vslam.outputs import atomic_write_bytes
from vslam.trajectory import Trajectory, read_trajectory

log = logging.getLogger(__name__)

MIN_TRAJECTORIES = 2  # one trajectory alone is its run folder's own trajectory.png
GAP_FACTOR = 3.0  # a time step over this many median steps is a gap (lost frames): the line breaks there
VSLAM_COLORS = ("#08519c", "#3182bd", "#6baed6", "#2171b5", "#4292c6", "#9ecae1")
BASELINE_COLORS = (("#a63603", "#e6550d", "#fd8d3c", "#d94801", "#f16913", "#fdae6b"),
                   ("#54278f", "#756bb1", "#9e9ac8", "#6a51a3", "#807dba", "#bcbddc"))


@dataclass
class Curve:
    """One repeat's trajectory as drawn: ``positions`` (N, 3) after alignment at ``timestamps``,
    its ``ate`` (None without ground truth or alignment), whether it could be ``aligned`` and how
    (``align``: ``se3`` or ``sim3``)."""

    label: str
    system: str
    repeat: int
    positions: np.ndarray
    ate: float | None
    aligned: bool
    align: str
    timestamps: np.ndarray
    reference: bool = False  # the one the others are aligned to (no ground truth)
    # per pose matched to the ground truth: its time and position error (the ATE's own errors)
    error_t: np.ndarray | None = None
    error: np.ndarray | None = None


def base_name(row: dict) -> tuple[str, str]:
    """``(run, system)`` of a row: ``desk@orbslam3`` -> ``("desk", "orbslam3")``."""
    system = row.get("system", "vslam") or "vslam"
    run, sep, suffix = str(row["name"]).rpartition("@")
    if sep and system != "vslam":
        return run, suffix
    return str(row["name"]), "vslam"


def overlay_groups(rows: Sequence[dict], output: str | Path) -> dict[str, list[dict]]:
    """Run name -> its successful rows that have a ``trajectory.txt`` (vslam repeats first, then
    each baseline's), for every run with at least :data:`MIN_TRAJECTORIES` of them."""
    output = Path(output)
    groups: dict[str, list[dict]] = {}
    for r in rows:
        if r.get("status", "ok") != "ok" or r.get("error") or not r.get("output"):
            continue
        if not (output / r["output"] / "trajectory.txt").is_file():
            continue
        groups.setdefault(base_name(r)[0], []).append(r)
    order = {"vslam": 0}
    return {run: sorted(g, key=lambda r: (order.get(base_name(r)[1], 1), base_name(r)[1], r.get("repeat", 0)))
            for run, g in groups.items() if len(g) >= MIN_TRAJECTORIES}


def _spec_of(run: str, meta: dict | None) -> dict:
    return next((s for s in (meta or {}).get("runs") or [] if isinstance(s, dict) and s.get("name") == run), {})


def sequence_ground_truth(group: Sequence[dict], output: Path, spec: dict) -> tuple[Trajectory | None, str]:
    """``(trajectory, source)``: the ground truth of the group's sequence (see the module
    docstring); ``(None, "")`` when there is none. Never raises: a problem is logged."""
    first = group[0]
    data = first.get("data") or spec.get("data")
    if data:
        try:
            from vslam.datasets import open_dataset
            from vslam.datasets.ground_truth import resolve_ground_truth
            from vslam.inertial.sensors import split_sensor

            sensor = first.get("sensor") or spec.get("sensor")
            ds = open_dataset(data, kind=spec.get("dataset"), sensor=split_sensor(sensor)[0] if sensor else None)
            truth = resolve_ground_truth(ds)
            if truth.trajectory is not None and len(truth.trajectory):
                return truth.trajectory, truth.file or str(data)
        except Exception as exc:  # noqa: BLE001 - ground truth is optional to the plot
            log.debug("overlay of %s: no ground truth from %s (%s)", base_name(first)[0], data, exc)
    for r in group:
        path = output / r["output"] / "groundtruth.txt"
        if path.is_file():
            try:
                return read_trajectory(path), str(path.relative_to(output))
            except (VslamError, OSError, ValueError) as exc:
                log.warning("overlay of %s: %s unreadable (%s)", base_name(r)[0], path, exc)
    return None, ""


def _with_gaps(timestamps: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """``positions`` with a NaN row wherever the time step is over :data:`GAP_FACTOR` median steps."""
    if len(timestamps) < 3:
        return positions
    dt = np.diff(timestamps)
    gaps = np.flatnonzero(dt > GAP_FACTOR * max(float(np.median(dt)), 1e-9))
    return np.insert(positions, gaps + 1, np.nan, axis=0) if len(gaps) else positions


def align_mode(row: dict, fallback: str | None = None) -> str:
    """The ATE's alignment of a row: Sim(3) for a monocular run, SE(3) otherwise."""
    return "sim3" if (row.get("sensor") or fallback) == "mono" else "se3"


def aligned_curves(group: Sequence[dict], output: str | Path, gt: Trajectory | None) -> list[Curve]:
    """Every row's trajectory aligned to ``gt`` (else to the first row's trajectory with at least
    3 poses, left as it is), as drawn."""
    from vslam.eval import evaluate_trajectories

    output = Path(output)
    trajs = [read_trajectory(output / r["output"] / "trajectory.txt") for r in group]
    ref = gt if gt is not None else next((t for t in trajs if len(t) >= 3), trajs[0])
    curves = []
    for r, est in zip(group, trajs):
        system = base_name(r)[1]
        mode = align_mode(r, group[0].get("sensor"))
        positions, ate, aligned, error_t, error = est.positions, None, False, None, None
        if est is ref:
            aligned = True
        elif len(est) >= 3:
            try:
                res = evaluate_trajectories(est, ref, align=mode)
            except VslamError as exc:
                log.warning("overlay: %s repeat %s not aligned (%s)", r["name"], r.get("repeat"), exc)
            else:
                positions, aligned = res.alignment.apply(est.T_world_cam)[:, :3, 3], True
                if gt is not None:
                    ate, error_t, error = float(res.ate.rmse), res.est_aligned.timestamps, res.ate_errors
        label = f"{system} #{r.get('repeat', 0)}" + (f" (ATE {ate:.4f} m)" if ate is not None else "")
        curves.append(Curve(label + ("" if aligned else " (not aligned)"), system, int(r.get("repeat", 0)),
                            positions, ate, aligned, mode, est.timestamps, est is ref, error_t, error))
    return curves


def _colors(curves: Sequence[Curve]) -> list[str]:
    systems = [s for s in dict.fromkeys(c.system for c in curves) if s != "vslam"]
    out, used = [], {}
    for c in curves:
        palette = (VSLAM_COLORS if c.system == "vslam"
                   else BASELINE_COLORS[systems.index(c.system) % len(BASELINE_COLORS)])
        k = used.get(c.system, 0)
        used[c.system] = k + 1
        out.append(palette[k % len(palette)])
    return out


def overlay_figure(run: str, curves: Sequence[Curve], gt: Trajectory | None, gt_source: str, mono: bool):
    """The figure of :func:`write_overlays` for one run (matplotlib Agg, no pyplot)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from vslam.eval.plot import AXIS_NAMES, fit_titles, top_view_axes

    pts = np.concatenate([c.positions for c in curves])
    gt_pos = _gt_span(gt, curves) if gt is not None else None
    a, b = top_view_axes(gt_pos if gt_pos is not None and len(gt_pos) >= 2 else pts) if len(pts) >= 2 else (0, 1)
    errors = any(c.error is not None for c in curves)
    fig = Figure(figsize=(7.2, 8.2 if errors else 6.0))
    FigureCanvasAgg(fig)
    grid = fig.add_gridspec(2, 1, height_ratios=(3.0, 1.1)) if errors else None
    ax = fig.add_subplot(grid[0]) if grid is not None else fig.add_subplot(1, 1, 1)
    if gt_pos is not None and len(gt_pos):
        ax.plot(gt_pos[:, a], gt_pos[:, b], "--", color="0.2", lw=1.6, label="ground truth", zorder=3)
    for c, color in zip(curves, _colors(curves)):
        line = _with_gaps(c.timestamps, c.positions)  # no line across lost frames
        ax.plot(line[:, a], line[:, b], "-", color=color, lw=1.2, alpha=0.85, label=c.label)
        if len(c.positions):
            ax.plot(c.positions[0, a], c.positions[0, b], "o", color=color, ms=4)
    unit = "arbitrary scale" if mono and gt is None else "m"
    ax.set_xlabel(f"{AXIS_NAMES[a]} [{unit}]")
    ax.set_ylabel(f"{AXIS_NAMES[b]} [{unit}]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize=7)
    modes = "/".join(sorted({"Sim(3)" if c.align == "sim3" else "SE(3)" for c in curves}))
    ref = f"aligned to the ground truth ({modes}, as the ATE)" if gt is not None else \
        f"no ground truth: aligned to {next((c for c in curves if c.reference), curves[0]).label} ({modes})"
    ax.set_title(f"{run}: {len(curves)} trajectories from above, {ref}", fontsize=10)
    if errors:
        _error_panel(fig.add_subplot(grid[1]), curves)
    if gt is not None and gt_source:
        fig.suptitle(f"ground truth: {gt_source}", fontsize=8, color="0.3")
    fit_titles(fig)
    return fig


def _error_panel(ax, curves: Sequence[Curve]) -> None:
    """Each curve's position error against the ground truth over time (seconds from the first pose)."""
    series = [(color, c.error_t, c.error) for c, color in zip(curves, _colors(curves)) if c.error is not None]
    t0 = min((t[0] for _, t, _ in series if len(t)), default=0.0)
    for color, t, err in series:
        line = _with_gaps(t, np.column_stack([t - t0, err]))
        ax.plot(line[:, 0], line[:, 1], "-", color=color, lw=1.0, alpha=0.85)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("position error [m]")
    ax.set_ylim(bottom=0.0)
    ax.grid(alpha=0.3)
    ax.set_title("position error of each trajectory above (its RMS is the ATE)", fontsize=9)


def _gt_span(gt: Trajectory, curves: Sequence[Curve]) -> np.ndarray:
    """The ground truth's positions over the trajectories' time span (one step of slack either side)."""
    t = gt.timestamps
    slack = float(np.median(np.diff(t))) if len(t) >= 2 else 0.0
    spans = [(c.timestamps[0], c.timestamps[-1]) for c in curves if len(c.timestamps)]
    if not spans:
        return gt.positions
    t0, t1 = min(s[0] for s in spans) - slack, max(s[1] for s in spans) + slack
    keep = (t >= t0) & (t <= t1)
    return gt.positions[keep] if keep.sum() >= 2 else gt.positions


def write_overlays(rows: Sequence[dict], output: str | Path, meta: dict | None = None,
                   dpi: int = 100) -> dict[str, Path]:
    """Write ``traj_<run>.png`` into ``output`` for every run of :func:`overlay_groups`; returns
    ``{"traj_<run>": path}``. A run whose plot cannot be made is logged and skipped."""
    output = Path(output)
    files: dict[str, Path] = {}
    for run, group in overlay_groups(rows, output).items():
        spec = _spec_of(run, meta)
        try:
            gt, source = sequence_ground_truth(group, output, spec)
            curves = aligned_curves(group, output, gt)
            fig = overlay_figure(run, curves, gt, source, mono=align_mode(group[0], spec.get("sensor")) == "sim3")
            buf = io.BytesIO()
            fig.savefig(buf, format="png", dpi=dpi)
        except (VslamError, OSError, ValueError) as exc:
            log.warning("no trajectory overlay for %s: %s", run, exc)
            continue
        files[f"traj_{run}"] = atomic_write_bytes(output / f"traj_{run}.png", buf.getvalue())
    return files


def overlays_markdown(files: dict[str, Any], output: str | Path | None = None) -> str:
    """The ``results.md`` section listing the overlay plots (empty string without any)."""
    items = [(k[len("traj_"):], Path(p)) for k, p in files.items() if str(k).startswith("traj_")]
    if not items:
        return ""
    lines = ["\n## Trajectories\n",
             "Every repeat's trajectory of a run (and its baseline's) in one plot, from above, each aligned "
             "to the ground truth as its ATE is (SE(3); Sim(3) for monocular), or to the first repeat when "
             "the sequence has no ground truth.\n"]
    for run, path in items:  # beside results.md
        lines.append(f"- `{run}`: [{path.name}]({path.name})")
    return "\n".join(lines) + "\n"
