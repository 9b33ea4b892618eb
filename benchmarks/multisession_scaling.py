"""How ``vslam map`` scales with the number of sessions (issue #26, "Scales" and "Parallel").

Renders the synthetic fleet once (:mod:`vslam.datasets.synthetic.fleet`: arcs ``s00 .. s31`` of the
room loop, consecutive arcs overlapping, plus ``lone`` which overlaps nothing), then maps fleets of
``N`` arcs + ``lone`` with ``vslam map`` (local executor, ``--workers W``, a fresh output folder
each) and reads ``sessions.json``: the wall time of the tracking, of the overlap search (one
bag-of-words index, every keyframe queried once), of the pair verification, of the merge stage (the
parallel rounds of tree merges) and of the pose graph + global BA + outputs, the candidate pairs
verified against all ``N (N - 1) / 2`` pairs, the components, and the ATE over every frame of the
largest component after ONE SE(3) alignment to the fleet's ground truth. With ``--sequential N``, the ``N``-arc fleet is mapped again
with ``--workers 1`` for the parallel speed-up (``--executor ray``: on a local Ray of that many CPUs).

    python benchmarks/multisession_scaling.py -o /tmp/msbench --sizes 2 4 8 16 32 --sequential 16

Writes ``DIR/results.json`` and prints the markdown table; ``--plot PNG`` draws the merge stage and the
overlap search against N log N (``--from-json DIR/results.json`` redraws an earlier run's).
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path



def fleet_ate(out: Path, fleet: Path, component: int = 0) -> tuple[float, dict[str, float], int]:
    """RMSE over every frame of every session of ``component`` after ONE SE(3) alignment of them all
    to the fleet's ground truth (``fleet/<name>/groundtruth.txt``, the room's frame); the
    per-session RMSE under that alignment; the number of frames (:func:`vslam.eval.joint.joint_ate`)."""
    from vslam.eval.joint import joint_ate
    from vslam.trajectory import read_tum

    comp = [s for s in json.loads((out / "sessions.json").read_text())["sessions"] if s.get("component") == component]
    j = joint_ate({s["name"]: read_tum(s["trajectory"]) for s in comp},
                  {s["name"]: read_tum(fleet / s["name"] / "groundtruth.txt") for s in comp})
    return j.rmse, j.per_name, j.frames


def write_spec(fleet: Path, n: int, lone: bool = True) -> Path:
    """``sessions.yaml`` for the first ``n`` arcs (+ ``lone``) of the rendered fleet."""
    from vslam.datasets.synthetic.fleet import LONE, session_name

    names = [session_name(k) for k in range(n)] + ([LONE] if lone else [])
    path = fleet / f"sessions_{n}.yaml"
    path.write_text("sessions:\n" + "".join(f"  - {{name: {s}, data: {s}, sensor: rgbd}}\n" for s in names))
    return path


def map_fleet(fleet: Path, n: int, out: Path, workers: int, executor: str = "local") -> dict:
    """One ``vslam map`` of the ``n``-arc fleet into ``out`` (a fresh folder); its figures."""
    import shutil

    shutil.rmtree(out, ignore_errors=True)
    cmd = [sys.executable, "-m", "vslam", "map", str(write_spec(fleet, n)), "-o", str(out),
           "--workers", str(workers), "--executor", executor, "--no-report"]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed:\n{proc.stderr[-3000:]}")
    res = json.loads((out / "sessions.json").read_text())
    ate, per, frames = fleet_ate(out, fleet)
    tm, idx = res["timing"], res["index"]
    return {
        "arcs": n, "sessions": idx["sessions"], "workers": workers, "keyframes": idx["keyframes"],
        "queries": idx["queries"], "candidate_pairs": idx["candidate_pairs"], "all_pairs": idx["all_pairs"],
        "verified": len(res["overlaps"]), "components": [len(c) for c in res["components"]],
        "lone_apart": ["lone"] in res["components"],
        "executor": res["executor"], "tracking_s": tm["sessions_s"], "search_s": tm["overlap_search_s"],
        "index_s": idx.get("search_s"), "verify_s": tm["verify_s"], "merge_s": tm["merge_s"],
        "finalize_s": tm["finalize_s"], "total_s": tm["total_s"], "wall_s": round(wall, 1),
        "merge_rounds": [[r["pairs"], r["wall_s"], [m.get("task_s") for m in r["merges"]]]
                         for r in res["merge_rounds"]],
        "pose_graph": res["component_maps"][0].get("pose_graph"),
        "ate_m": round(ate, 4), "worst_session_m": round(max(per.values()), 4), "frames": frames,
        "task_s": {s["name"]: s.get("task_s") for s in res["sessions"]},
        "pair_task_s": [c.get("task_s") for c in res["candidates"]],
    }


def table(rows: list[dict]) -> str:
    head = ("| N arcs (+ lone) | workers | keyframes | pairs verified / all | components | tracking s | "
            "overlap search s | verify s | merge s (rounds) | pose graph + global BA s | total s | "
            "ATE one SE(3) m (worst session) |")
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for r in rows:
        lines.append(
            f"| {r['arcs']} (+1) | {r['workers']} | {r['keyframes']} | {r['candidate_pairs']} / {r['all_pairs']} | "
            f"{' + '.join(map(str, r['components']))} | {r['tracking_s']} | {r['search_s']} | {r['verify_s']} | "
            f"{r['merge_s']} ({len(r['merge_rounds'])}) | {r['finalize_s']} | {r['total_s']} | "
            f"{r['ate_m']} ({r['worst_session_m']}) |")
    return "\n".join(lines)


def merge_stage(r: dict) -> tuple[float, float]:
    """``(wall s, work s)`` of the merge stage of one row: the rounds' wall time plus the pose graph +
    global BA + outputs, and the same with every merge task's own time summed (the work)."""
    work = sum(sum(times) for _, _, times in r["merge_rounds"])
    return r["merge_s"] + r["finalize_s"], work + r["finalize_s"]


def plot(rows: list[dict], path: Path) -> None:
    """Merge stage (wall and work) and overlap search against N, with N log N and N^2 through the
    first point of the merge work."""
    import numpy as np
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    rows = [r for r in rows if r["workers"] == rows[0]["workers"]]
    n = np.array([r["arcs"] for r in rows], float)
    wall, work = np.array([merge_stage(r) for r in rows]).T
    fig = Figure(figsize=(6.5, 4.5), dpi=100)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    ax.loglog(n, work, "o-", label="merge stage: work (every merge task + pose graph + global BA + outputs)")
    ax.loglog(n, wall, "s-", label=f"merge stage: wall time, {rows[0]['workers']} workers")
    ax.loglog(n, [r["search_s"] for r in rows], "^-", label="overlap search")
    nlogn = n * np.log2(np.maximum(n, 2))
    ax.loglog(n, work[0] * nlogn / nlogn[0], ":", color="grey", label="N log N (through the first point)")
    ax.loglog(n, work[0] * (n / n[0]) ** 2, "--", color="grey", label="N^2 (through the first point)")
    ax.set_xlabel("sessions N (arcs of the synthetic fleet)")
    ax.set_ylabel("seconds")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7)
    ax.set_title("vslam map: merge stage and overlap search vs N", fontsize=9)
    fig.tight_layout()
    fig.savefig(path)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("-o", "--output", type=Path, required=True)
    p.add_argument("--sizes", type=int, nargs="+", default=[2, 4, 8, 16, 32])
    p.add_argument("--frames", type=int, default=50, help="frames per session")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--sequential", type=int, default=0, help="also map this many arcs with --workers 1")
    p.add_argument("--executor", choices=("local", "ray"), default="local")
    p.add_argument("--plot", type=Path, help="draw the merge stage and the overlap search against N log N")
    p.add_argument("--from-json", type=Path, help="an earlier run's results.json: table and plot only")
    args = p.parse_args(argv)
    if args.from_json:
        rows = json.loads(args.from_json.read_text())
        if args.plot:
            plot(rows, args.plot)
        print(table(rows))
        return 0
    from vslam.datasets.synthetic.fleet import render_fleet

    fleet = args.output / "fleet"
    t0 = time.perf_counter()
    render_fleet(fleet, max(args.sizes + [args.sequential]), args.frames)
    print(f"fleet rendered in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    rows = []
    runs = [(n, args.workers) for n in args.sizes] + ([(args.sequential, 1)] if args.sequential else [])
    for n, w in runs:
        rows.append(map_fleet(fleet, n, args.output / f"map_{n}_w{w}", w, args.executor))
        print(json.dumps({k: v for k, v in rows[-1].items() if not k.endswith("task_s")}), file=sys.stderr)
        (args.output / "results.json").write_text(json.dumps(rows, indent=1))
    if args.plot:
        plot(rows, args.plot)
    print(table(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
