"""``vslam report``: one self-contained HTML page for a run folder or a benchmark folder.

Self-contained means no external URL at all: plots are PNGs embedded as base64 ``data:`` URIs,
styles are inline, and a tiny inline script marks ``<body data-report-status="ready">`` once every
image has decoded (``naturalWidth > 0``) without a script error (what the headless-browser test
checks).

For a run folder (``stats.json``, ``trajectory.txt``, optionally ``sparse.ply``,
``groundtruth.txt``): the summary numbers; the trajectory from above against ground truth (from
``groundtruth.txt`` in the folder, else the dataset at ``stats.json``'s ``path``), aligned as the
run's ATE is (SE(3), Sim(3) for monocular) and coloured by the position error, with the loop
closures of ``stats.json`` drawn between the two frames they join; the error along the path; the
mean time per pipeline stage; the sparse map from above.

For a benchmark folder (``results.json``): the per-run table (median, min-max), ATE and fps plots,
every (run, repeat) with a link to its own run report (written next to its run folder).
"""
from __future__ import annotations

import base64
import html
import io
import json
import logging
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from vslam.errors import VslamError
from vslam.textfile import open_text
from vslam.outputs import atomic_write_text, check_output_file, inside

log = logging.getLogger(__name__)

MAX_MAP_POINTS = 100_000

_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;margin:24px auto;max-width:1100px;
color:#222;padding:0 16px}
h1{font-size:1.5em;margin-bottom:.2em}h2{font-size:1.2em;margin-top:1.6em;border-bottom:1px solid #ddd}
table{border-collapse:collapse;font-size:.9em;margin:.5em 0}td,th{border:1px solid #ddd;padding:3px 8px;
text-align:right}th{background:#f4f4f4}td:first-child,th:first-child{text-align:left}
.fig{display:inline-block;vertical-align:top;margin:6px 12px 6px 0}.fig img{max-width:100%;border:1px solid #eee}
.note{color:#666;font-size:.9em}.fail{color:#a50f15}code{background:#f4f4f4;padding:0 3px}
"""

_SCRIPT = """
(function(){
  var errors = [];
  window.addEventListener('error', function(e){ errors.push(String(e.message || e)); }, true);
  function check(){
    var imgs = document.images, ok = 0;
    for (var i = 0; i < imgs.length; i++) { if (imgs[i].complete && imgs[i].naturalWidth > 0) ok++; }
    var b = document.body;
    b.setAttribute('data-images-total', String(imgs.length));
    b.setAttribute('data-images-ok', String(ok));
    b.setAttribute('data-script-errors', String(errors.length));
    b.setAttribute('data-report-status', (ok === imgs.length && errors.length === 0) ? 'ready' : 'broken');
  }
  if (document.readyState === 'complete') check(); else window.addEventListener('load', check);
})();
"""


# ----------------------------------------------------------------------------------------------
# small HTML helpers
# ----------------------------------------------------------------------------------------------
def _esc(x: Any) -> str:
    return html.escape(str(x), quote=True)


def _png_data_uri(fig) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def _img(uri: str, alt: str) -> str:
    return f'<div class="fig"><img src="{uri}" alt="{_esc(alt)}" title="{_esc(alt)}"></div>'


def _figure(w: float, h: float):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(w, h), dpi=100)
    FigureCanvasAgg(fig)
    return fig


def _fmt(v: Any) -> str:
    if v is None:
        return "-"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        return f"{v:.4g}" if abs(v) < 1e4 else f"{v:.0f}"
    return str(v)


def render_page(title: str, body: str) -> str:
    """A complete HTML document with the inline style and image-check script."""
    return (
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
        f"<meta name=\"viewport\" content=\"width=device-width\"><title>{_esc(title)}</title>"
        f"<style>{_CSS}</style></head>\n<body>\n{body}\n<script>{_SCRIPT}</script>\n</body></html>\n"
    )


# ----------------------------------------------------------------------------------------------
# a run folder
# ----------------------------------------------------------------------------------------------
@dataclass
class RunData:
    """Everything a run report shows, loaded from a run folder."""

    folder: Path
    stats: dict
    est: Any = None  # Trajectory | None
    gt: Any = None
    gt_source: str = ""
    evaluation: Any = None  # vslam.eval.EvalResult | None
    T_gt_est: np.ndarray | None = None
    notes: list[str] = field(default_factory=list)
    frame_times: np.ndarray | None = None  # timestamp of every dataset frame index
    points: tuple[np.ndarray, np.ndarray | None] | None = None


def _open_dataset_of(stats: dict):
    from vslam.datasets import KINDS, open_dataset

    path = stats.get("path")
    if not path or not Path(path).exists():
        raise VslamError(f"the sequence {path!r} named in stats.json is not available here")
    kind = stats.get("dataset") if stats.get("dataset") in KINDS else None
    return open_dataset(path, kind=kind, sensor=stats.get("sensor"))


#: the type each known ``stats.json`` field must have (a crafted file fails with one line)
_STATS_TYPES: dict[str, tuple[type, ...]] = {
    "frames": (int,), "tracked": (int,), "lost": (int,), "skipped_frames": (int,), "start_frame": (int,),
    "loops": (list,), "stage_ms": (dict,), "path": (str,), "sensor": (str,), "dataset": (str,),
    "error": (str,), "fps": (int, float), "wall_s": (int, float), "ate_rmse": (int, float),
}


def _check_stats(path: Path, stats: Any) -> None:
    """Raise :class:`VslamError` naming the field when ``stats.json`` is not what ``vslam run`` writes."""
    if not isinstance(stats, dict):
        raise VslamError(f"{path}: expected a JSON object as written by `vslam run`")
    for key, types in _STATS_TYPES.items():
        v = stats.get(key)
        if v is not None and (not isinstance(v, types) or isinstance(v, bool)):
            raise VslamError(f"{path}: field {key!r} is {type(v).__name__} {v!r:.40}, expected "
                             f"{' or '.join(t.__name__ for t in types)}; fix or regenerate the file")
    for i, loop in enumerate(stats.get("loops") or []):
        if not isinstance(loop, (list, dict)):
            raise VslamError(f"{path}: loops[{i}] is {loop!r:.40}, expected a list [query frame, match frame, ...]")
    for k, v in (stats.get("stage_ms") or {}).items():
        if not isinstance(v, (int, float)) or isinstance(v, bool):
            raise VslamError(f"{path}: stage_ms[{k!r}] is {v!r:.40}, expected a number of milliseconds")


def load_run(folder: str | Path) -> RunData:
    """Load a run folder's stats, trajectory, ground truth (aligned and evaluated) and sparse map."""
    from vslam.eval import evaluate_trajectories, read_trajectory

    folder = Path(folder)
    if not (folder / "stats.json").is_file():
        raise VslamError(f"{folder}: no stats.json; pass a `vslam run` output folder or a `vslam bench` folder")
    try:
        stats = json.loads(open_text(folder / "stats.json", VslamError).read())
    except ValueError as exc:
        raise VslamError(f"{folder / 'stats.json'}: not valid JSON ({exc})") from None
    _check_stats(folder / "stats.json", stats)
    run = RunData(folder=folder, stats=stats)
    traj_path = folder / "trajectory.txt"
    if traj_path.is_file():
        try:
            run.est = read_trajectory(traj_path, "tum", duplicates="keep_last")
        except VslamError as exc:
            run.notes.append(f"trajectory not readable: {exc}")
    else:
        run.notes.append("no trajectory.txt in the run folder")
    ds = None
    try:
        ds = _open_dataset_of(stats)
        run.frame_times = np.asarray(ds.timestamps, dtype=float)
    except Exception as exc:  # noqa: BLE001 - the report works without the dataset
        log.info("dataset of %s not opened: %s", folder, exc)
    gt_file = folder / "groundtruth.txt"
    if gt_file.is_file():
        try:
            run.gt, run.gt_source = read_trajectory(gt_file), str(gt_file.name)
        except VslamError as exc:
            run.notes.append(f"groundtruth.txt not readable: {exc}")
    if run.gt is None and ds is not None:
        try:
            run.gt = ds.ground_truth()
            run.gt_source = f"dataset {stats.get('path')}" if run.gt is not None else ""
        except Exception as exc:  # noqa: BLE001
            run.notes.append(f"ground truth of the dataset not readable: {exc}")
    if run.gt is None:
        run.notes.append("no ground truth (neither groundtruth.txt nor a readable dataset at stats.json's path)")
    if run.est is not None and run.gt is not None and len(run.est) >= 3:
        mode = "sim3" if stats.get("sensor") == "mono" else "se3"
        try:
            run.evaluation = evaluate_trajectories(run.est, run.gt, align=mode)
            run.T_gt_est = run.evaluation.alignment
        except VslamError as exc:
            run.notes.append(f"evaluation against ground truth failed: {exc}")
    ply = folder / "sparse.ply"
    if ply.is_file():
        from vslam.report.ply import read_ply_points

        try:
            run.points = read_ply_points(ply, MAX_MAP_POINTS)
        except VslamError as exc:
            run.notes.append(f"sparse.ply not readable: {exc}")
    return run


def _aligned_positions(run: RunData) -> np.ndarray:
    """Every estimated position, in the ground-truth frame when an alignment exists."""
    T = run.est.T_world_cam
    if run.evaluation is not None:
        T = run.evaluation.alignment.apply(T)
    return T[:, :3, 3]


def loop_positions(run: RunData, positions: np.ndarray) -> list[tuple[np.ndarray, np.ndarray, list]]:
    """``(query_xyz, match_xyz, loop)`` for every loop of ``stats.json`` whose two frames have a pose.

    Frame indices become timestamps through the dataset (or, without it, the trajectory rows when
    every frame was tracked) and then the nearest trajectory pose within half a frame.
    """
    loops = run.stats.get("loops") or []
    if not loops or run.est is None or len(run.est) == 0:
        return []
    ts = run.est.timestamps
    if run.frame_times is not None:
        times = run.frame_times
        offset = 0
    elif len(ts) == run.stats.get("frames"):
        times, offset = ts, int(run.stats.get("start_frame", 0) or 0)
    else:
        return []
    dt = float(np.median(np.diff(ts))) if len(ts) > 1 else 1.0
    out = []
    for loop in loops:
        try:
            q, m = int(loop[0]) - offset, int(loop[1]) - offset
        except (TypeError, ValueError, IndexError):
            continue
        if not (0 <= q < len(times) and 0 <= m < len(times)):
            continue
        idx = []
        for t in (times[q], times[m]):
            j = int(np.clip(np.searchsorted(ts, t), 1, len(ts) - 1)) if len(ts) > 1 else 0
            j = j - 1 if len(ts) > 1 and abs(ts[j - 1] - t) <= abs(ts[j] - t) else j
            idx.append(j if abs(ts[j] - t) <= 0.5 * dt + 1e-6 else None)
        if None not in idx:
            out.append((positions[idx[0]], positions[idx[1]], list(loop)))
    return out


def top_axes(T_world_cam: np.ndarray | None, points: np.ndarray | None = None) -> tuple[int, int]:
    """The two world axes of a view "from above".

    Cameras in every supported dataset are held roughly upright (car, hand, MAV), so the world
    axis best aligned with the cameras' mean y (image-down) axis is the vertical; the other two are
    plotted. When no axis dominates (mean |component| < 0.5) fall back to the two axes of largest
    extent of the positions (or ``points``).
    """
    from vslam.eval.plot import top_view_axes

    if T_world_cam is not None and len(T_world_cam):
        down = np.mean(np.asarray(T_world_cam)[:, :3, 1], axis=0)
        if np.max(np.abs(down)) >= 0.5:
            vertical = int(np.argmax(np.abs(down)))
            a, b = (i for i in range(3) if i != vertical)
            return a, b
    pts = points if points is not None else (np.asarray(T_world_cam)[:, :3, 3] if T_world_cam is not None else None)
    return top_view_axes(pts) if pts is not None and len(pts) >= 2 else (0, 1)


def _gt_span(run: RunData):
    """The ground truth over the estimate's time span (plus one frame either side)."""
    gt = run.gt
    if gt is None or run.est is None or len(run.est) == 0 or len(gt) < 2:
        return gt
    slack = float(np.median(np.diff(gt.timestamps)))
    keep = (gt.timestamps >= run.est.timestamps[0] - slack) & (gt.timestamps <= run.est.timestamps[-1] + slack)
    return gt.subset(np.flatnonzero(keep)) if keep.sum() >= 2 else gt


def plot_trajectory(run: RunData) -> str | None:
    """Top view: ground truth, the aligned estimate coloured by position error, loops (PNG URI)."""
    from matplotlib.collections import LineCollection

    if run.est is None or len(run.est) == 0:
        return None
    est = _aligned_positions(run)
    gt_traj = _gt_span(run)
    gt = gt_traj.positions if gt_traj is not None else None
    a, b = top_axes(gt_traj.T_world_cam if gt_traj is not None else run.est.T_world_cam)
    fig = _figure(6.4, 5.2)
    ax = fig.add_subplot(1, 1, 1)
    if gt is not None:
        ax.plot(gt[:, a], gt[:, b], "-", color="0.55", lw=1.5, label="ground truth")
    ev = run.evaluation
    if ev is not None and len(ev.ate_errors) >= 2:
        p = ev.est_aligned.positions
        segs = np.stack([p[:-1][:, [a, b]], p[1:][:, [a, b]]], axis=1)
        from matplotlib.colors import Normalize

        lc = LineCollection(segs, cmap="viridis", lw=2.0,
                            norm=Normalize(0.0, max(float(ev.ate_errors.max()), 1e-9)))
        lc.set_array(0.5 * (ev.ate_errors[:-1] + ev.ate_errors[1:]))
        ax.add_collection(lc)
        fig.colorbar(lc, ax=ax, label="position error [m]", shrink=0.8)
        ax.plot([], [], "-", color="#21918c", lw=2, label="estimate (aligned)")
    else:
        ax.plot(est[:, a], est[:, b], "-", color="#3182bd", lw=1.5,
                label="estimate" + (" (aligned)" if ev is not None else ""))
    ax.plot(est[0, a], est[0, b], "o", color="k", ms=5, label="start")
    loops = loop_positions(run, est)
    for i, (q, m, _loop) in enumerate(loops):
        ax.plot([q[a], m[a]], [q[b], m[b]], "--", color="#e31a1c", lw=1.2, label="loop closure" if i == 0 else None)
        ax.plot([q[a], m[a]], [q[b], m[b]], "o", mfc="none", color="#e31a1c", ms=7)
    ax.set_xlabel(f"{'xyz'[a]} [m]")
    ax.set_ylabel(f"{'xyz'[b]} [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.autoscale_view()
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    ax.set_title("trajectory from above" + (f" ({ev.alignment.mode} aligned)" if ev is not None else ""))
    fig.tight_layout()
    return _png_data_uri(fig)


def plot_error(run: RunData) -> str | None:
    """Position error along the ground-truth path (distance travelled) (PNG URI)."""
    ev = run.evaluation
    if ev is None or len(ev.ate_errors) < 2:
        return None
    gt = ev.gt_matched.positions
    dist = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(gt, axis=0), axis=1))])
    fig = _figure(6.4, 3.0)
    ax = fig.add_subplot(1, 1, 1)
    ax.plot(dist, ev.ate_errors, "-", color="#08519c", lw=1.2)
    ax.axhline(ev.ate.rmse, color="#e31a1c", lw=1, ls="--", label=f"RMSE {ev.ate.rmse:.4f} m")
    ax.set_ylim(0.0, max(float(ev.ate_errors.max()), 1e-9) * 1.15)
    ax.set_xlabel("distance along the ground-truth path [m]")
    ax.set_ylabel("position error [m]")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title("error along the path")
    fig.tight_layout()
    return _png_data_uri(fig)


PER_KEYFRAME_STAGES = ("local_ba",)  # stats.json's stage_ms holds these per call (per keyframe), not per frame


def split_stage_times(stats: dict) -> tuple[dict[str, float], dict[str, float]]:
    """``(per-frame ms, per-keyframe ms)`` of ``stats["stage_ms"]`` (``total`` left out)."""
    stage_ms = {k: float(v) for k, v in (stats.get("stage_ms") or {}).items()
                if isinstance(v, (int, float)) and k != "total"}
    per_kf = {k: v for k, v in stage_ms.items() if k in PER_KEYFRAME_STAGES}
    return {k: v for k, v in stage_ms.items() if k not in per_kf}, per_kf


def plot_stages(stats: dict) -> str | None:
    """Mean milliseconds per frame of every tracking stage, and per keyframe of the mapping stages
    (local BA), drawn apart (PNG URI)."""
    per_frame, per_kf = split_stage_times(stats)
    if not per_frame and not per_kf:
        return None
    names = sorted(per_frame, key=per_frame.get) + sorted(per_kf, key=per_kf.get)
    values = [per_frame.get(n, per_kf.get(n)) for n in names]
    colors = ["#6baed6" if n in per_frame else "#fd8d3c" for n in names]
    labels = [n if n in per_frame else f"{n} (per keyframe)" for n in names]
    fig = _figure(6.4, 0.35 * len(names) + 1.3)
    ax = fig.add_subplot(1, 1, 1)
    ax.barh(range(len(names)), values, color=colors)
    ax.set_yticks(range(len(names)), labels, fontsize=8)
    ax.set_xlabel("mean time [ms]: per frame (blue), per keyframe (orange)")
    total = (stats.get("stage_ms") or {}).get("total")
    ax.set_title("time per stage" + (f" (tracking total {float(total):.1f} ms/frame)" if total is not None else ""))
    ax.grid(axis="x", alpha=0.3)
    fig.tight_layout()
    return _png_data_uri(fig)


def plot_map(run: RunData) -> str | None:
    """The sparse map from above with the (unaligned) estimated trajectory (PNG URI)."""
    if run.points is None or len(run.points[0]) == 0:
        return None
    xyz, rgb = run.points
    traj = run.est.positions if run.est is not None and len(run.est) else None
    a, b = top_axes(run.est.T_world_cam if traj is not None else None, xyz)
    fig = _figure(6.4, 5.2)
    ax = fig.add_subplot(1, 1, 1)
    colors = rgb / 255.0 if rgb is not None else "#444444"
    ax.scatter(xyz[:, a], xyz[:, b], s=1.0, c=colors, linewidths=0, label=f"{len(xyz)} map points")
    if traj is not None:
        ax.plot(traj[:, a], traj[:, b], "-", color="#e6550d", lw=1.2, label="trajectory")
    ax.set_xlabel(f"{'xyz'[a]} [m]")
    ax.set_ylabel(f"{'xyz'[b]} [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize=8, markerscale=6)
    ax.set_title("sparse map from above (SLAM frame)")
    fig.tight_layout()
    return _png_data_uri(fig)


_SUMMARY_KEYS = (
    ("sensor", "sensor"), ("dataset", "dataset"), ("path", "sequence"), ("frames", "frames"),
    ("tracked", "tracked"), ("lost", "lost"), ("keyframes", "keyframes"), ("map_points", "map points"),
    ("fps", "frames/s"), ("wall_s", "wall time [s]"), ("ate_rmse", "ATE RMSE [m]"),
    ("rpe_trans_rmse", "RPE trans RMSE [m]"), ("rpe_rot_deg_rmse", "RPE rot RMSE [deg]"),
    ("matched_poses", "matched poses"), ("scale", "Sim(3) scale"), ("error", "error"),
)


def run_body(run: RunData, title: str | None = None) -> str:
    """The HTML body of a run report."""
    s = run.stats
    title = title or f"vslam run: {run.folder.name}"
    parts = [f"<h1>{_esc(title)}</h1>", f'<p class="note">run folder <code>{_esc(run.folder)}</code></p>']
    rows = [f"<tr><td>{_esc(label)}</td><td>{_esc(_fmt(s.get(key)))}</td></tr>"
            for key, label in _SUMMARY_KEYS if s.get(key) is not None]
    rows.append(f"<tr><td>loop closures</td><td>{len(s.get('loops') or [])}</td></tr>")
    if run.evaluation is not None:
        ev = run.evaluation
        rows.append(f"<tr><td>ATE RMSE recomputed here [m]</td><td>{ev.ate.rmse:.4f}</td></tr>")
        rows.append(f"<tr><td>ground truth</td><td>{_esc(run.gt_source)}</td></tr>")
    parts.append('<h2>Summary</h2><table id="summary">' + "".join(rows) + "</table>")
    if s.get("sensor") == "mono":
        parts.append('<p class="note">monocular run: the map and trajectory scale is arbitrary; the ATE is '
                     'computed after a Sim(3) alignment (rotation, translation and scale) to the ground truth.</p>')
    if s.get("error"):
        parts.append(f'<p class="fail">the run failed: {_esc(s["error"])}</p>')
    parts.append("<h2>Trajectory</h2>")
    figs = [(plot_trajectory(run), "trajectory from above vs ground truth"), (plot_error(run), "error along the path")]
    shown = [_img(uri, alt) for uri, alt in figs if uri]
    parts.append("".join(shown) if shown else '<p class="note">no trajectory to show</p>')
    loops = s.get("loops") or []
    if loops:
        lrows = "".join(f"<tr><td>{_esc(l[0])}</td><td>{_esc(l[1])}</td><td>{_esc(l[2] if len(l) > 2 else '-')}</td></tr>"
                        for l in loops if isinstance(l, (list, tuple)) and len(l) >= 2)
        parts.append("<h2>Loop closures</h2><table><tr><th>query frame</th><th>matched frame</th>"
                     f"<th>inliers</th></tr>{lrows}</table>")
    uri = plot_stages(s)
    parts.append("<h2>Time per stage</h2>" + (_img(uri, "time per stage") if uri else
                                             '<p class="note">no stage timings in stats.json</p>'))
    uri = plot_map(run)
    if uri:
        parts.append("<h2>Sparse map</h2>" + _img(uri, "sparse map from above"))
    if run.notes:
        parts.append("<h2>Notes</h2><ul>" + "".join(f'<li class="note">{_esc(n)}</li>' for n in run.notes) + "</ul>")
    return "\n".join(parts)


def run_report_html(folder: str | Path, title: str | None = None) -> str:
    """The whole HTML page of a run folder's report."""
    run = load_run(folder)
    return render_page(title or f"vslam run {Path(folder).name}", run_body(run, title))


# ----------------------------------------------------------------------------------------------
# a benchmark folder
# ----------------------------------------------------------------------------------------------
def bench_report_html(folder: str | Path, output: str | Path | None = None, run_reports: bool = True) -> str:
    """The HTML page of a benchmark folder; with ``run_reports`` every run folder also gets its own
    ``report.html``, linked from the table (links are relative to ``output``'s folder)."""
    from vslam.bench.results import METRICS, plot_per_run, read_results, summarize

    folder = Path(folder)
    data = read_results(folder)
    rows = data["rows"]
    meta = data.get("meta") or {}
    out_dir = Path(output).resolve().parent if output is not None else folder.resolve()
    summary = summarize(rows)
    parts = ["<h1>vslam benchmark</h1>"]
    info = ", ".join(f"{k} {_esc(meta[k])}" for k in ("spec", "executor", "created", "host") if meta.get(k))
    parts.append(f'<p class="note">{info}</p>' if info else "")
    if meta.get("description"):
        parts.append(f"<p>{_esc(meta['description'])}</p>")
    head = "".join(f"<th>{_esc(t)}</th>" for t in ["run", "sensor", "ok/repeats", "frames"] + [m[1] for m in METRICS])
    trs = []
    for s in summary:
        def cell(key: str, fmt: str) -> str:
            st = s.get(key)
            if st is None:
                return "-"
            if st["n"] == 1 or st["min"] == st["max"]:
                return fmt.format(st["median"])
            spread = f"{fmt.format(st['min'])}–{fmt.format(st['max'])}"
            return f"{fmt.format(st['median'])} <span class=\"note\">({spread})</span>"

        cls = ' class="fail"' if s["ok"] < s["repeats"] else ""
        name = _esc(s["name"])
        trs.append(f"<tr><td><a href=\"#run-{name}\">{name}</a></td><td>{_esc(s['sensor'] or '-')}</td>"
                   f"<td{cls}>{s['ok']}/{s['repeats']}</td><td>{_esc(_fmt(s.get('frames')))}</td>"
                   + "".join(f"<td>{cell(k, f)}</td>" for k, _, f in METRICS) + "</tr>")
    parts.append("<h2>Results per run</h2><p class=\"note\">median over successful repeats (min–max)</p>"
                 f'<table id="results"><tr>{head}</tr>{"".join(trs)}</table>')
    parts.append("<h2>Plots</h2>")
    for key, label in (("ate_rmse", "ATE RMSE [m]"), ("fps", "frames per second"), ("realtime_factor", "x real time")):
        buf = plot_per_run(rows, key, label)
        parts.append(_img("data:image/png;base64," + base64.b64encode(buf).decode("ascii"), label))
    parts.append("<h2>Every run</h2>")
    cols = ["repeat", "status", "frames", "tracked", "ate_rmse", "rpe_trans_rmse", "fps", "realtime_factor", "wall_s"]
    by_name: dict[str, list[dict]] = {}
    for r in rows:
        by_name.setdefault(r["name"], []).append(r)
    for name, group in by_name.items():
        trs = []
        for r in group:
            link = "-"
            try:
                run_dir = inside(folder, r.get("output", f"runs/{name}/{r['repeat']}"))
            except VslamError as exc:
                raise VslamError(f"{folder / 'results.json'}: row {name!r} repeat {r['repeat']}: {exc}") from None
            if run_reports and (run_dir / "stats.json").is_file():
                try:
                    page = run_dir / "report.html"
                    atomic_write_text(page, run_report_html(run_dir, f"{name} repeat {r['repeat']}"))
                    link = f'<a href="{_esc(os.path.relpath(page.resolve(), out_dir))}">report</a>'
                except Exception as exc:  # noqa: BLE001 - one broken run must not break the page
                    link = f'<span class="fail">report failed: {_esc(exc)}</span>'
            cells = "".join(f"<td>{_esc(_fmt(r.get(c)))}</td>" for c in cols)
            err = f'<tr><td colspan="{len(cols) + 1}" class="fail">{_esc(r["error"])}</td></tr>' if r.get("error") else ""
            trs.append(f"<tr>{cells}<td>{link}</td></tr>{err}")
        head = "".join(f"<th>{_esc(c)}</th>" for c in cols) + "<th>report</th>"
        parts.append(f'<h3 id="run-{_esc(name)}">{_esc(name)}</h3><table><tr>{head}</tr>{"".join(trs)}</table>')
    return render_page("vslam benchmark", "\n".join(parts))


def write_report(path: str | Path, output: str | Path, run_reports: bool = True) -> Path:
    """Write the report of a run folder (``stats.json``) or a benchmark folder (``results.json``)."""
    path = Path(path)
    output = Path(output)
    if not path.is_dir():
        raise VslamError(f"{path}: not a folder; pass a `vslam run` or `vslam bench` output folder")
    check_output_file(output, "report")
    if (path / "results.json").is_file():
        page = bench_report_html(path, output, run_reports=run_reports)
    elif (path / "stats.json").is_file():
        page = run_report_html(path)
    else:
        raise VslamError(f"{path}: neither results.json (a bench folder) nor stats.json (a run folder) found")
    atomic_write_text(output, page)
    return output
