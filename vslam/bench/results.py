"""Benchmark results: ``results.json`` (one row per run and repeat), ``results.md`` (median and
min-max spread per run), and PNG plots of ATE and frames per second per run, and of every
repeat's trajectory of a run in one plot (:mod:`vslam.bench.overlay`).

Statistics per run use the repeats that succeeded and report the median with the min-max range;
a metric missing from every repeat (no ground truth) is shown as ``-``.
"""
from __future__ import annotations

import datetime as _dt
import io
import json
import math
import platform
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from vslam.bench.overlay import overlays_markdown, write_overlays
from vslam.errors import VslamError
from vslam.outputs import atomic_write_bytes, atomic_write_text
from vslam.textfile import open_text

#: metrics summarized per run: (row key, column title, number format)
METRICS = (
    ("ate_rmse", "ATE RMSE [m]", "{:.4f}"),
    ("rpe_trans_rmse", "RPE trans RMSE [m]", "{:.4f}"),
    ("fps", "frames/s", "{:.1f}"),
    ("realtime_factor", "x real time", "{:.2f}"),
    ("wall_s", "wall [s]", "{:.1f}"),
)

PLOTS = (("ate_rmse", "ATE RMSE [m]", "ate.png"), ("fps", "frames per second", "fps.png"))


def _finite(values: Sequence[Any]) -> np.ndarray:
    out = [float(v) for v in values if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)]
    return np.asarray(out, dtype=float)


def summarize(rows: Sequence[dict]) -> list[dict]:
    """Per run name (in first-seen order): repeats, successes, and for every metric in
    :data:`METRICS` (plus ``tracked_fraction``) the ``median``, ``min`` and ``max`` over successful
    repeats (None when no repeat has it)."""
    order: list[str] = []
    by_name: dict[str, list[dict]] = {}
    for r in rows:
        if r["name"] not in by_name:
            order.append(r["name"])
            by_name[r["name"]] = []
        by_name[r["name"]].append(r)
    out = []
    for name in order:
        group = by_name[name]
        ok = [r for r in group if r.get("status", "ok") == "ok" and not r.get("error")]
        s: dict[str, Any] = {
            "name": name,
            "sensor": next((r.get("sensor") for r in group if r.get("sensor")), None),
            "system": group[0].get("system", "vslam"),
            "repeats": len(group),
            "ok": len(ok),
            "frames": next((r.get("frames") for r in ok if r.get("frames") is not None), None),
            "errors": sorted({str(r["error"]) for r in group if r.get("error")}),
            "paced": any(bool(r.get("paced")) for r in ok),
        }
        tracked = [r["tracked"] / r["frames"] for r in ok if r.get("frames") and r.get("tracked") is not None]
        metrics = {key: [r.get(key) for r in ok] for key, _, _ in METRICS}
        metrics["tracked_fraction"] = tracked
        metrics["ate_common"] = [r.get("ate_common") for r in ok]  # vs a baseline, frames both tracked
        metrics["common_frames"] = [r.get("common_frames") for r in ok]
        metrics["ate_between"] = [r.get("ate_between") for r in ok]  # the two systems' distance on them
        metrics["error_correlation"] = [r.get("error_correlation") for r in ok]
        for key, values in metrics.items():
            v = _finite(values)
            s[key] = None if len(v) == 0 else {
                "median": float(np.median(v)), "min": float(v.min()), "max": float(v.max()), "n": int(len(v)),
            }
        out.append(s)
    return out


def _fmt(stat: dict | None, fmt: str) -> str:
    if stat is None:
        return "-"
    med = fmt.format(stat["median"])
    if stat["n"] == 1 or stat["min"] == stat["max"]:
        return med
    return f"{med} ({fmt.format(stat['min'])}–{fmt.format(stat['max'])})"


def markdown_table(summary: Sequence[dict]) -> str:
    """The per-run table: median (min–max) of every metric over the successful repeats."""
    head = ["run", "sensor", "ok/repeats", "frames", "tracked"] + [title for _, title, _ in METRICS]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for s in summary:
        tf = s.get("tracked_fraction")
        cells = [s["name"], s.get("sensor") or "-", f"{s['ok']}/{s['repeats']}",
                 str(s["frames"]) if s.get("frames") is not None else "-",
                 _fmt({**tf, "median": 100 * tf["median"], "min": 100 * tf["min"], "max": 100 * tf["max"]},
                      "{:.0f}") + " %" if tf else "-"]
        cells += [_fmt(s.get(key), fmt) for key, _, fmt in METRICS]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def _ratio(ours: dict | None, theirs: dict | None) -> float | None:
    if ours is None or theirs is None or not theirs["median"]:
        return None
    return ours["median"] / theirs["median"]


def baseline_comparison(summary: Sequence[dict]) -> list[dict]:
    """vslam next to each baseline (rows ``<run>@<system>``) of the same benchmark: per pair the
    medians of ATE RMSE, frames/s and tracked share, and the ratios vslam / baseline
    (``ate_ratio`` < 1: vslam is more accurate; ``fps_ratio`` > 1: vslam is faster)."""
    by_name = {s["name"]: s for s in summary}
    out = []
    for base in summary:
        run, sep, system = base["name"].rpartition("@")
        if not sep or base.get("system", "vslam") == "vslam" or run not in by_name:
            continue
        ours = by_name[run]

        def med(s: dict, key: str) -> float | None:
            return s[key]["median"] if s.get(key) else None

        out.append({
            "run": run, "system": system, "sensor": ours.get("sensor") or base.get("sensor"),
            "ate_vslam": med(ours, "ate_rmse"), "ate_baseline": med(base, "ate_rmse"),
            "ate_ratio": _ratio(ours.get("ate_rmse"), base.get("ate_rmse")),
            "fps_vslam": med(ours, "fps"), "fps_baseline": med(base, "fps"),
            "fps_ratio": _ratio(ours.get("fps"), base.get("fps")),
            "tracked_vslam": med(ours, "tracked_fraction"), "tracked_baseline": med(base, "tracked_fraction"),
            "baseline_paced": bool(base.get("paced")),
            # on the frames both tracked (vslam.bench.common_frames), medians over the repeats
            "ate_common_vslam": med(ours, "ate_common"),
            "ate_common_baseline": med(base, "ate_common"),
            "ate_common_ratio": _ratio(ours.get("ate_common"), base.get("ate_common")),
            "common_frames": med(base, "common_frames"),
            "ate_between": med(base, "ate_between"),
            "error_correlation": med(base, "error_correlation"),
        })
    return out


def _apart(between: float | None, correlation: float | None) -> str:
    if between is None:
        return "-"
    return f"{between:.4f}" + ("" if correlation is None else f" ({correlation:.2f})")


def comparison_markdown(comparison: Sequence[dict]) -> str:
    """The vslam-vs-baseline table of :func:`baseline_comparison` (empty string without baselines)."""
    if not comparison:
        return ""

    def num(v: float | None, fmt: str) -> str:
        return "-" if v is None else fmt.format(v)

    lines = ["| run | sensor | baseline | ATE vslam [m] | ATE baseline [m] | ATE ratio | ATE both tracked: vslam / "
             "baseline [m] | ratio | frames both tracked | apart [m] (error correlation) | frames/s vslam | "
             "frames/s baseline | speed ratio | tracked vslam | tracked baseline |", "|" + "---|" * 15]
    for c in comparison:
        fps_b = num(c["fps_baseline"], "{:.1f}") + (" (paced)" if c["baseline_paced"] else "")
        lines.append("| " + " | ".join([
            c["run"], c.get("sensor") or "-", c["system"], num(c["ate_vslam"], "{:.4f}"),
            num(c["ate_baseline"], "{:.4f}"), num(c["ate_ratio"], "{:.2f}"),
            f'{num(c.get("ate_common_vslam"), "{:.4f}")} / {num(c.get("ate_common_baseline"), "{:.4f}")}',
            num(c.get("ate_common_ratio"), "{:.2f}"), num(c.get("common_frames"), "{:.0f}"),
            _apart(c.get("ate_between"), c.get("error_correlation")),
            num(c["fps_vslam"], "{:.1f}"), fps_b,
            num(c["fps_ratio"], "{:.2f}"),
            num(None if c["tracked_vslam"] is None else 100 * c["tracked_vslam"], "{:.0f} %"),
            num(None if c["tracked_baseline"] is None else 100 * c["tracked_baseline"], "{:.0f} %")]) + " |")
    return "\n".join(lines) + "\n"


def results_markdown(rows: Sequence[dict], meta: dict | None = None) -> str:
    """The whole ``results.md``: header, the table, failures, and how the numbers were made."""
    meta = meta or {}
    summary = summarize(rows)
    parts = ["# Benchmark results\n"]
    if meta.get("description"):
        parts.append(meta["description"].strip() + "\n")
    workers = meta.get("workers")
    executor = None
    if meta.get("executor"):
        executor = f"executor {meta['executor']}" + (f" ({_plural(workers, 'worker')})" if workers else "")
    info = [f"spec `{meta['spec']}`" if meta.get("spec") else None, executor,
            f"created {meta['created']}" if meta.get("created") else None,
            f"host {meta['host']}" if meta.get("host") else None]
    info_s = ", ".join(i for i in info if i)
    if info_s:
        parts.append(info_s + ".\n")
    parts.append("Median over successful repeats, (min–max) when they differ. `x real time` is frames/s "
                 "divided by the sensor's frame rate over the frames used; `tracked` is the share of "
                 "frames with a pose.\n")
    parts.append(markdown_table(summary))
    comparison = comparison_markdown(baseline_comparison(summary))
    if comparison:
        parts.append("\n## vslam vs baseline (same benchmark run)\n")
        parts.append("Medians over successful repeats. ATE ratio = vslam / baseline (< 1: vslam more "
                     "accurate); speed ratio = vslam frames/s / baseline frames/s (> 1: vslam faster). "
                     "A `(paced)` baseline was fed at the sensor rate (times its `pace_rate`, see its "
                     "stats.json), so its frames/s is capped by that rate and the speed ratio is an upper "
                     "bound (vslam may be relatively slower than shown). `ATE both tracked`: each system "
                     "scored on the frames both have a pose for (same repeat, own alignment), so a system "
                     "that drops hard frames is not scored on its easy ones only. `apart`: the RMS distance "
                     "between the two trajectories on those frames, each aligned to the ground truth, and in "
                     "brackets the correlation of their errors: near 1, with the two closer to each other than "
                     "to the ground truth, both systems make the same error there (in the ground truth, the "
                     "calibration or the sequence), and the ATE ratio says little about which is better.\n")
        parts.append(comparison)
    failed = [r for r in rows if r.get("error")]
    if failed:
        parts.append("\n## Failed runs\n")
        for r in failed:
            err = str(r["error"]).replace("\n", " ")
            parts.append(f"- `{r['name']}` repeat {r['repeat']}: {err} (`{r.get('output', '')}`)")
        parts.append("")
    return "\n".join(parts) + "\n"


def plot_per_run(rows: Sequence[dict], key: str, label: str, dpi: int = 100) -> bytes:
    """PNG bytes: one line per run, every successful repeat as a dot and the median as a bar."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    summary = summarize(rows)
    names = [s["name"] for s in summary]
    fig = Figure(figsize=(7.0, 0.45 * max(len(names), 2) + 1.2), dpi=dpi)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    for y, s in enumerate(summary):
        vals = _finite([r.get(key) for r in rows
                        if r["name"] == s["name"] and r.get("status", "ok") == "ok" and not r.get("error")])
        if len(vals):
            ax.barh(y, float(np.median(vals)), color="#9ecae1", height=0.6)
            ax.plot(vals, np.full(len(vals), y), "o", color="#08519c", ms=4)
        else:
            ax.text(0, y, "  no value", va="center", fontsize=8, color="#a50f15")
    ax.set_yticks(range(len(names)), names, fontsize=8)
    ax.set_ylim(len(names) - 0.5, -0.5)
    ax.set_xlabel(label)
    ax.grid(axis="x", alpha=0.3)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    return buf.getvalue()


def write_results(rows: Sequence[dict], output: str | Path, meta: dict | None = None,
                  plots: bool = True) -> dict[str, Path]:
    """Write ``results.json``, ``results.md`` and (with ``plots``) ``ate.png`` / ``fps.png`` and
    the trajectory overlays ``traj_<run>.png`` (:mod:`vslam.bench.overlay`, listed in
    ``results.md``) into ``output``; returns ``{kind: path}`` (``traj_<run>`` for the overlays)."""
    output = Path(output)
    output.mkdir(parents=True, exist_ok=True)
    meta = dict(meta or {})
    meta.setdefault("created", _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M:%S UTC"))
    meta.setdefault("host", f"{platform.node()} ({platform.machine()}, {_cpu_count()} CPUs)")
    files = {}
    summary = summarize(rows)
    data = {"rows": list(rows), "summary": summary, "meta": meta}
    comparison = baseline_comparison(summary)
    if comparison:
        data["baseline_comparison"] = comparison
    # each file atomically: a full disk leaves the previous results whole, never a truncated file
    files["json"] = atomic_write_text(output / "results.json", json.dumps(data, indent=2, default=_json_default))
    overlays: dict[str, Path] = {}
    if plots:
        for key, label, fname in PLOTS:
            files[key] = atomic_write_bytes(output / fname, plot_per_run(rows, key, label))
        overlays = write_overlays(rows, output, meta)  # traj_<run>.png: every repeat's trajectory in one plot
        files.update(overlays)
    files["md"] = atomic_write_text(output / "results.md",
                                    results_markdown(rows, meta) + overlays_markdown(overlays, output))
    return files


def read_results(folder_or_file: str | Path) -> dict:
    """Load ``results.json`` (from its folder or the file itself)."""
    path = Path(folder_or_file)
    if path.is_dir():
        path = path / "results.json"
    if not path.is_file():
        raise VslamError(f"{path}: no results.json here; run `vslam bench` first")
    try:
        data = json.loads(open_text(path, VslamError).read())
    except ValueError as exc:
        raise VslamError(f"{path}: not valid JSON ({exc})") from None
    if not isinstance(data, dict) or not isinstance(data.get("rows"), list):
        raise VslamError(f"{path}: expected {{\"rows\": [...]}}; is this a vslam bench folder?")
    for i, row in enumerate(data["rows"]):
        _check_row(path, i, row)
    return data


#: the type each known field of a ``results.json`` row must have (required: name, repeat)
_ROW_TYPES: dict[str, tuple[type, ...]] = {
    "name": (str,), "repeat": (int,), "status": (str,), "output": (str,), "error": (str,),
    "frames": (int,), "tracked": (int,), "ate_rmse": (int, float), "fps": (int, float), "wall_s": (int, float),
}


def _check_row(path: Path, i: int, row: Any) -> None:
    """Raise :class:`VslamError` naming the row and field of a malformed ``results.json`` row."""
    if not isinstance(row, dict):
        raise VslamError(f"{path}: rows[{i}] is {type(row).__name__}, expected an object; regenerate it with `vslam bench`")
    for key in ("name", "repeat"):
        if key not in row:
            raise VslamError(f"{path}: rows[{i}] lacks {key!r}; regenerate it with `vslam bench`")
    for key, types in _ROW_TYPES.items():
        v = row.get(key)
        if v is not None and (not isinstance(v, types) or isinstance(v, bool)):
            raise VslamError(f"{path}: rows[{i}].{key} is {v!r:.40}, expected {' or '.join(t.__name__ for t in types)}")
    out = row.get("output")
    if out is not None and (Path(out).is_absolute() or ".." in Path(out).parts):
        raise VslamError(f"{path}: rows[{i}].output {out!r} leaves the bench folder; outputs must be relative "
                         "paths inside it")


def _plural(n: int, word: str) -> str:
    return f"{n} {word}{'' if n == 1 else 's'}"


def _cpu_count() -> int:
    import os

    return os.cpu_count() or 1


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.floating):
        return float(obj)
    if isinstance(obj, (np.ndarray,)):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"not JSON serializable: {type(obj)}")
