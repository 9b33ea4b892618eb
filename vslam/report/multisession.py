"""The report page of a ``vslam map`` result (issue #26): ``OUT/report.html``.

Read from ``OUT/sessions.json`` and ``OUT/trajectories/<name>.txt`` only: every session's
trajectory in one plot per component (its common frame, seen from above, one colour per session),
the session graph (nodes = sessions, grouped by component; edges = verified overlaps labelled with
their inlier counts, solid where a merge used them, dashed where only the pose graph did, red
dotted where the merge failed; failed sessions as grey crosses), the largest component's
topological map, and the tables of sessions, components and timings.

The topological maps are drawn here (:func:`draw_topologies`: ``topology.png`` beside each
component's ``topology.json``), not by ``vslam map``'s finalize task: a worker process that only
drew that one figure paid matplotlib's import for it, 0.5 s of the command's serial end on the
synthetic fleet (benchmarks/RESULTS.md, issue #26 round 6).
"""
from __future__ import annotations

import base64
import json
import logging
from pathlib import Path

import numpy as np

from vslam.errors import VslamError
from vslam.report.page import esc, fmt_value, img_tag, new_figure, png_data_uri, render_page

log = logging.getLogger(__name__)


def _colours(n: int):
    from matplotlib import colormaps

    cmap = colormaps["tab20" if n > 10 else "tab10"]
    return [cmap(i % cmap.N) for i in range(n)]


def plot_trajectories(doc: dict, trajectories: dict[str, np.ndarray]) -> str | None:
    """One axes per component (at most 4), every session's positions from above, coloured by session."""
    from vslam.report.charts import top_axes

    comps = [c for c in doc.get("components", []) if any(n in trajectories for n in c)][:4]
    if not comps:
        return None
    names = [s["name"] for s in doc["sessions"]]
    colour = dict(zip(names, _colours(len(names))))
    fig = new_figure(6.0 * len(comps), 5.5)
    for k, comp in enumerate(comps):
        ax = fig.add_subplot(1, len(comps), k + 1)
        T = np.concatenate([trajectories[n] for n in comp if n in trajectories])
        a, b = top_axes(T)
        for n in comp:
            if n in trajectories:
                p = trajectories[n][:, :3, 3]
                ax.plot(p[:, a], p[:, b], "-", lw=1.2, color=colour[n], label=n)
                ax.plot(p[:1, a], p[:1, b], "o", ms=3, color=colour[n])
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_title(f"component {k}: {len(comp)} session{'s' * (len(comp) != 1)}")
        ax.set_xlabel("xyz"[a])
        ax.set_ylabel("xyz"[b])
        ax.grid(alpha=0.3)
        if len(comp) <= 20:
            ax.legend(fontsize=7, ncol=2 if len(comp) > 8 else 1)
    fig.tight_layout()
    return png_data_uri(fig)


def graph_layout(doc: dict) -> dict[str, tuple[float, float]]:
    """Node positions: each component on its own circle (radius by size), the circles in a row;
    failed sessions in a row below."""
    pos: dict[str, tuple[float, float]] = {}
    x0 = 0.0
    for comp in doc.get("components", []):
        r = 0.0 if len(comp) == 1 else max(1.0, len(comp) / 6.0)
        for i, n in enumerate(comp):
            a = 2.0 * np.pi * i / len(comp)
            pos[n] = (x0 + r + r * np.cos(a), r * np.sin(a))
        x0 += 2.0 * r + 1.5
    failed = [s["name"] for s in doc["sessions"] if s["name"] not in pos]
    for i, n in enumerate(failed):
        pos[n] = (1.5 * i, -max([abs(p[1]) for p in pos.values()] + [1.0]) - 1.5)
    return pos


def plot_session_graph(doc: dict) -> str | None:
    """The session graph (module docstring)."""
    if not doc.get("sessions"):
        return None
    pos = graph_layout(doc)
    xs = np.array([p[0] for p in pos.values()])
    fig = new_figure(min(max(5.0, 1.2 + 0.9 * (xs.max() - xs.min())), 16.0), 6.0)
    ax = fig.add_subplot(1, 1, 1)
    for e in doc.get("overlaps", []):
        (xa, ya), (xb, yb) = pos[e["a"]], pos[e["b"]]
        style = ":" if e.get("merge_error") else ("-" if e.get("in_tree") else "--")
        ax.plot([xa, xb], [ya, yb], style, color="#a50f15" if e.get("merge_error") else "#555",
                lw=0.8 + 0.6 * np.log10(max(e.get("inliers", 1), 1)), zorder=1)
        ax.text(0.5 * (xa + xb), 0.5 * (ya + yb), str(e.get("inliers")), fontsize=7, ha="center", va="center",
                bbox={"boxstyle": "round,pad=0.15", "fc": "white", "ec": "none", "alpha": 0.8}, zorder=2)
    comp_of = {n: i for i, c in enumerate(doc.get("components", [])) for n in c}
    colours = _colours(max(len(doc.get("components", [])), 1))
    for s in doc["sessions"]:
        x, y = pos[s["name"]]
        if s["name"] in comp_of:
            ax.scatter([x], [y], s=260, color=colours[comp_of[s["name"]]], edgecolor="k", zorder=3)
        else:
            ax.scatter([x], [y], s=120, marker="x", color="#888", zorder=3)
        ax.text(x, y - 0.28, s["name"] + ("" if s["name"] in comp_of else " (failed)"), fontsize=8, ha="center",
                va="top", zorder=4)
    ax.set_title("session graph: verified overlaps (inliers)\nsolid: merged along, dashed: pose graph only, "
                 "dotted red: merge failed", fontsize=8)
    ax.set_axis_off()
    ax.set_aspect("equal", adjustable="datalim")
    ax.margins(0.15)
    fig.tight_layout()
    return png_data_uri(fig)


def _table(head: list[str], rows: list[list]) -> str:
    th = "".join(f"<th>{esc(h)}</th>" for h in head)
    body = "".join("<tr>" + "".join(f"<td>{esc(fmt_value(v))}</td>" for v in r) + "</tr>" for r in rows)
    return f"<table><tr>{th}</tr>{body}</table>"


def _component_folder(out: Path, i: int) -> Path:
    """Where ``vslam map`` wrote component ``i`` (the largest into ``out``)."""
    return out if i == 0 else out / "components" / str(i)


def draw_topologies(folder: str | Path) -> list[Path]:
    """``topology.png`` of each component of a ``vslam map`` result, from its ``topology.json``
    (:func:`vslam.reconstruction.topology.plot_topology`; axes in arbitrary scale where a session is
    monocular). Returns the files written; a component whose JSON is unreadable is skipped with a
    warning (the page is still written)."""
    from vslam.reconstruction.topology import plot_topology, read_topology

    out = Path(folder)
    try:
        doc = json.loads((out / "sessions.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return []  # the page says why
    sensors = {s["name"]: s.get("sensor") or (s.get("spec") or {}).get("sensor") for s in doc.get("sessions", [])}
    written = []
    for i, names in enumerate(doc.get("components", [])):
        src = _component_folder(out, i) / "topology.json"
        if not src.is_file():
            continue
        try:
            nodes, edges = read_topology(src)
        except VslamError as exc:
            log.warning("%s: not drawn (%s)", src, exc)
            continue
        if nodes:
            unit = "arbitrary scale" if any(sensors.get(n) == "mono" for n in names) else "m"
            written.append(plot_topology(src.with_suffix(".png"), nodes, edges, unit=unit))
    return written


def _topology_img(out: Path) -> str:
    png = out / "topology.png"
    if not png.is_file():
        return "<p class=\"note\">no topology.png (`vslam report` draws it from topology.json)</p>"
    return img_tag("data:image/png;base64," + base64.b64encode(png.read_bytes()).decode("ascii"),
                   "topological map of the largest component")


def multisession_report_html(folder: str | Path) -> str:
    """The page of a ``vslam map`` output folder (module docstring)."""
    from vslam.trajectory import read_tum

    out = Path(folder)
    try:
        doc = json.loads((out / "sessions.json").read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise VslamError(f"{out}: no readable sessions.json ({exc}); pass the output folder of `vslam map`") from None
    trajectories = {}
    for s in doc.get("sessions", []):
        if s.get("trajectory") and Path(s["trajectory"]).is_file():
            trajectories[s["name"]] = read_tum(s["trajectory"]).T_world_cam
    parts = [f"<h1>vslam map: {esc(out.name)}</h1>",
             f"<p class=\"note\">{len(doc['sessions'])} sessions, {len(doc.get('overlaps', []))} verified overlaps, "
             f"{len(doc.get('components', []))} components; executor {esc(doc.get('executor'))}</p>"]
    traj = plot_trajectories(doc, trajectories)
    graph = plot_session_graph(doc)
    parts.append("<h2>Trajectories (each component in its common frame)</h2>")
    parts.append(img_tag(traj, "trajectories by session") if traj else "<p class=\"note\">no trajectory</p>")
    parts.append("<h2>Session graph</h2>")
    parts.append(img_tag(graph, "session graph") if graph else "")
    parts.append("<h2>Topological map (largest component: keyframes, odometry and covisibility edges)</h2>")
    parts.append(_topology_img(out))
    parts.append("<h2>Sessions</h2>")
    parts.append(_table(["session", "status", "frames", "keyframes", "component", "reused", "error"], [
        [s["name"], s["status"], s.get("frames"), s.get("keyframes"), s.get("component"), s.get("reused"),
         s.get("error")] for s in doc["sessions"]]))
    parts.append("<h2>Verified overlaps</h2>")
    parts.append(_table(["a", "b", "inliers", "transform", "scale", "merged along", "merge error"], [
        [e["a"], e["b"], e.get("inliers"), e.get("transform"), e.get("scale"), e.get("in_tree"), e.get("merge_error")]
        for e in doc.get("overlaps", [])]))
    parts.append("<h2>Components</h2>")
    parts.append(_table(["#", "sessions", "keyframes", "points", "merges", "pose graph overlap edges", "folder"], [
        [i, ", ".join(c["sessions"]), c.get("keyframes"), c.get("points"), len(c.get("merges", [])),
         (c.get("pose_graph") or {}).get("overlap"), c.get("folder")]
        for i, c in enumerate(doc.get("component_maps", []))]))
    parts.append("<h2>Timing (s)</h2>")
    parts.append(_table(list(doc.get("timing", {})), [list(doc.get("timing", {}).values())]))
    return render_page(f"vslam map {out.name}", "\n".join(parts))


def write_multisession_report(folder: str | Path, output: str | Path | None = None) -> Path:
    """Write the page (default ``folder/report.html``); returns its path."""
    from vslam.outputs import atomic_write_text

    path = Path(output) if output is not None else Path(folder) / "report.html"
    if path.suffix.lower() not in (".html", ".htm"):
        raise VslamError(f"{path}: the report is an HTML page; name it *.html (e.g. report.html)")
    draw_topologies(folder)
    atomic_write_text(path, multisession_report_html(folder))
    return path
