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
mean time per pipeline stage; an inertial run's IMU velocity and biases per frame (``imu_states.csv``,
IMU-only frames shaded); the sparse map from above.

For a benchmark folder (``results.json``): the per-run table (median, min-max), ATE and fps plots,
every (run, repeat) with a link to its own run report (written next to its run folder).
"""
from __future__ import annotations

import base64
import logging
import os
from pathlib import Path

from vslam.errors import OutputError, VslamError
from vslam.outputs import RUN_OUTPUTS, atomic_write_text, check_output_file, inside, lies_inside, refuse_inputs
from vslam.report.charts import plot_error, plot_map, plot_stages, plot_trajectory, split_stage_times  # noqa: F401
from vslam.report.imu_chart import load_imu_states, plot_imu_states
from vslam.report.page import esc, fmt_value, img_tag, render_page
from vslam.report.run_data import RunData, load_run, loop_positions

__all__ = ["bench_report_html", "load_run", "loop_positions", "run_body", "run_report_html", "write_report"]

log = logging.getLogger(__name__)

_SUMMARY_KEYS = (
    ("sensor", "sensor"), ("dataset", "dataset"), ("path", "sequence"), ("frames", "frames"),
    ("tracked", "tracked"), ("imu_only_frames", "posed by the IMU alone"), ("lost", "lost"), ("keyframes", "keyframes"), ("map_points", "map points"),
    ("fps", "frames/s"), ("wall_s", "wall time [s]"), ("ate_rmse", "ATE RMSE [m]"),
    ("rpe_trans_rmse", "RPE trans RMSE [m]"), ("rpe_rot_deg_rmse", "RPE rot RMSE [deg]"),
    ("matched_poses", "matched poses"), ("scale", "Sim(3) scale"), ("map", "map"), ("map_loaded", "map loaded"),
    ("placed_at_frame", "first frame placed at frame"), ("error", "error"),
)


def _summary_rows(s: dict) -> list[str]:
    """The summary table's rows; a ``vslam localize`` folder (``localized`` in stats) shows the
    localized frames and their percentage, then the tracked and relocalized ones they are made of."""
    keys = list(_SUMMARY_KEYS)
    values = dict(s)
    loc, frames = s.get("localized"), s.get("frames")
    if isinstance(loc, int) and isinstance(frames, int):
        i = keys.index(("tracked", "tracked"))
        keys[i:i + 1] = [("localized", "localized"), ("tracked", "tracked (from the previous frame)"),
                         ("relocalizations", "relocalized")]
        values["localized"] = f"{loc}/{frames} ({100.0 * loc / max(frames, 1):.1f} %)"
    return [f"<tr><td>{esc(label)}</td><td>{esc(fmt_value(values.get(key)))}</td></tr>"
            for key, label in keys if values.get(key) is not None]


def run_body(run: RunData, title: str | None = None) -> str:
    """The HTML body of a run report."""
    s = run.stats
    title = title or f"vslam {'localize' if 'localized' in s else 'run'}: {run.folder.name}"
    parts = [f"<h1>{esc(title)}</h1>", f'<p class="note">run folder <code>{esc(run.folder)}</code></p>']
    rows = _summary_rows(s)
    rows.append(f"<tr><td>loop closures</td><td>{len(s.get('loops') or [])}</td></tr>")
    if run.evaluation is not None:
        ev = run.evaluation
        rows.append(f"<tr><td>ATE RMSE recomputed here [m]</td><td>{ev.ate.rmse:.4f}</td></tr>")
        rows.append(f"<tr><td>ground truth</td><td>{esc(run.gt_source)}</td></tr>")
    parts.append('<h2>Summary</h2><table id="summary">' + "".join(rows) + "</table>")
    if s.get("sensor") == "mono":
        ate = ("the ATE is computed after a Sim(3) alignment (rotation, translation and scale) to the ground "
               "truth." if run.evaluation is not None else "there is no ground truth to fix it.")
        parts.append(f'<p class="note">monocular run: the map and trajectory scale is arbitrary; {ate}</p>')
    if s.get("error"):
        parts.append(f'<p class="fail">the run failed: {esc(s["error"])}</p>')
    parts.append("<h2>Trajectory</h2>")
    figs = [(plot_trajectory(run), "trajectory from above" + (" vs ground truth" if run.gt is not None else "")),
            (plot_error(run), "error along the path")]
    shown = [img_tag(uri, alt) for uri, alt in figs if uri]
    parts.append("".join(shown) if shown else '<p class="note">no trajectory to show</p>')
    loops = s.get("loops") or []
    if loops:
        lrows = "".join(f"<tr><td>{esc(l[0])}</td><td>{esc(l[1])}</td><td>{esc(l[2] if len(l) > 2 else '-')}</td></tr>"
                        for l in loops if isinstance(l, (list, tuple)) and len(l) >= 2)
        parts.append("<h2>Loop closures</h2><table><tr><th>query frame</th><th>matched frame</th>"
                     f"<th>inliers</th></tr>{lrows}</table>")
    uri = plot_stages(s)
    parts.append("<h2>Time per stage</h2>" + (img_tag(uri, "time per stage") if uri else
                                             '<p class="note">no stage timings in stats.json</p>'))
    uri = plot_imu_states(load_imu_states(run.folder, run.notes))
    if uri:
        parts.append("<h2>IMU: velocity and biases</h2>" + img_tag(uri, "IMU velocity and biases"))
    uri = plot_map(run)
    if uri:
        parts.append("<h2>Sparse map</h2>" + img_tag(uri, "sparse map from above"))
    if run.notes:
        parts.append("<h2>Notes</h2><ul>" + "".join(f'<li class="note">{esc(n)}</li>' for n in run.notes) + "</ul>")
    return "\n".join(parts)


def run_report_html(folder: str | Path, title: str | None = None, gt: str | Path | None = None) -> str:
    """The whole HTML page of a run folder's report (``gt``: see :func:`load_run`)."""
    run = load_run(folder, gt)
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
    info = ", ".join(f"{k} {esc(meta[k])}" for k in ("spec", "executor", "created", "host") if meta.get(k))
    parts.append(f'<p class="note">{info}</p>' if info else "")
    if meta.get("description"):
        parts.append(f"<p>{esc(meta['description'])}</p>")
    head = "".join(f"<th>{esc(t)}</th>" for t in ["run", "sensor", "ok/repeats", "frames"] + [m[1] for m in METRICS])
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
        name = esc(s["name"])
        trs.append(f"<tr><td><a href=\"#run-{name}\">{name}</a></td><td>{esc(s['sensor'] or '-')}</td>"
                   f"<td{cls}>{s['ok']}/{s['repeats']}</td><td>{esc(fmt_value(s.get('frames')))}</td>"
                   + "".join(f"<td>{cell(k, f)}</td>" for k, _, f in METRICS) + "</tr>")
    parts.append("<h2>Results per run</h2><p class=\"note\">median over successful repeats (min–max)</p>"
                 f'<table id="results"><tr>{head}</tr>{"".join(trs)}</table>')
    parts.append("<h2>Plots</h2>")
    for key, label in (("ate_rmse", "ATE RMSE [m]"), ("fps", "frames per second"), ("realtime_factor", "x real time")):
        buf = plot_per_run(rows, key, label)
        parts.append(img_tag("data:image/png;base64," + base64.b64encode(buf).decode("ascii"), label))
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
                    link = f'<a href="{esc(os.path.relpath(page.resolve(), out_dir))}">report</a>'
                except Exception as exc:  # noqa: BLE001 - one broken run must not break the page
                    link = f'<span class="fail">report failed: {esc(exc)}</span>'
            cells = "".join(f"<td>{esc(fmt_value(r.get(c)))}</td>" for c in cols)
            err = f'<tr><td colspan="{len(cols) + 1}" class="fail">{esc(r["error"])}</td></tr>' if r.get("error") else ""
            trs.append(f"<tr>{cells}<td>{link}</td></tr>{err}")
        head = "".join(f"<th>{esc(c)}</th>" for c in cols) + "<th>report</th>"
        parts.append(f'<h3 id="run-{esc(name)}">{esc(name)}</h3><table><tr>{head}</tr>{"".join(trs)}</table>')
    return render_page("vslam benchmark", "\n".join(parts))


#: files of a run or bench folder that a report reads (besides any existing non-HTML file there)
REPORT_INPUTS = RUN_OUTPUTS + ("results.json", "results.md", "groundtruth.txt")


def _refuse_report_onto_input(folder: Path, output: Path, gt: str | Path | None = None) -> None:
    """The report never lands on its folder, its ground truth file or a file inside the folder that
    it reads (``stats.json``, ``results.json`` ...): only a new file or an HTML page may go there."""
    refuse_inputs(output, (folder, gt if gt is not None and str(gt) != "none" else None), "report")
    if not lies_inside(output, folder):
        return
    top = Path(os.path.realpath(output)).relative_to(os.path.realpath(folder)).parts[0]  # the file, or map/ ...
    if top in REPORT_INPUTS or (output.is_file() and output.suffix.lower() not in (".html", ".htm")):
        raise OutputError(f"{output}: is a file of {folder} that the report reads; writing the report there "
                          "would destroy it, choose another name (e.g. report.html)")


def write_report(path: str | Path, output: str | Path, run_reports: bool = True, gt: str | Path | None = None) -> Path:
    """Write the report of a run folder (``stats.json``) or a benchmark folder (``results.json``);
    ``gt`` chooses a run's ground truth (a file, ``"none"``; see :func:`load_run`)."""
    path = Path(path)
    output = Path(output)
    if not path.is_dir():
        raise VslamError(f"{path}: not a folder; pass a `vslam run` or `vslam bench` output folder")
    _refuse_report_onto_input(path, output, gt)
    check_output_file(output, "report")
    if (path / "results.json").is_file():
        page = bench_report_html(path, output, run_reports=run_reports)
    elif (path / "stats.json").is_file():
        page = run_report_html(path, gt=gt)
    else:
        raise VslamError(f"{path}: neither results.json (a bench folder) nor stats.json (a run folder) found")
    atomic_write_text(output, page)
    return output
