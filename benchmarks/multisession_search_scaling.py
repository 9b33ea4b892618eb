"""How the overlap search of ``vslam map`` grows with the number of sessions (issue #26, "Scales").

Takes the run folders of a mapped fleet (``DIR/sessions/<name>/``, e.g. the 32-arc row of
``benchmarks/multisession_scaling.py``) and times :func:`vslam.multisession.overlap.candidate_pairs`
on N of them, N = 2, 4, ... up to the fleet's size, then beyond it on the fleet's sessions repeated
under other names (the index does not care that they are copies: every keyframe still queries an
index of all N sessions' keyframes). Reports the search's parts (reading the databases, the
queries), the keyframes and queries, the pairs it hands to verification against all
``N (N - 1) / 2``, and what verifying all pairs would cost at the measured mean pair-task time of
the mapped fleet (``sessions.json`` ``candidates[].task_s``). Writes ``results.json``, a plot
(``--plot``) and prints the markdown table.

    python benchmarks/multisession_search_scaling.py /tmp/msbench/map_32_w2 --sizes 2 4 8 16 32 64 128 256 \
        --plot benchmarks/multisession_search_scaling.png -o /tmp/msbench/search.json
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path


def sessions_of(result: Path, n: int) -> dict[str, Path]:
    """``n`` sessions of the mapped fleet in ``result`` (arcs first, the lone one last; repeated as
    ``<name>~<k>`` beyond the fleet's size)."""
    doc = json.loads((result / "sessions.json").read_text())
    ok = [(s["name"], Path(s["folder"])) for s in doc["sessions"] if s["status"] == "ok" and s["name"] != "lone"]
    return {(name if k == 0 else f"{name}~{k}"): folder
            for i in range(n) for k, (name, folder) in [(i // len(ok), ok[i % len(ok)])]}


def measure(result: Path, n: int, repeats: int = 3, budget: int = 4096) -> dict:
    from vslam.multisession.overlap import candidate_pairs

    folders = sessions_of(result, n)
    best = None
    for _ in range(repeats):
        t0 = time.perf_counter()
        pairs, stats = candidate_pairs(folders, 3, budget=budget or 1 << 62)
        wall = time.perf_counter() - t0
        if best is None or wall < best["search_s"]:
            best = {"sessions": n, "keyframes": stats["keyframes"], "queries": stats["queries"],
                    "candidate_pairs": len(pairs), "all_pairs": stats["all_pairs"], "search_s": round(wall, 4),
                    "read_s": stats.get("read_s"), "query_s": round(wall - (stats.get("read_s") or 0.0), 4)}
    return best


def plot(rows: list[dict], pair_s: float, path: Path, every_word: list[float] | None = None) -> None:
    """The curves of ``rows``; ``every_word``: search times with every word of each query (the first
    version's per-query work, measured with ``--budget 0``), drawn beside them."""
    import numpy as np
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    n = np.array([r["sessions"] for r in rows], float)
    s = np.array([r["search_s"] for r in rows])
    fig = Figure(figsize=(6.5, 4.5), dpi=100)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    ax.loglog(n, s, "o-", label="overlap search (measured)")
    if every_word:
        ax.loglog(n[: len(every_word)], every_word, "o--", color="C3", label="overlap search, every word of a query")
    ax.loglog(n, [r["candidate_pairs"] * pair_s for r in rows], "s-", label=f"verify candidates ({pair_s:.2f} s/pair)")
    ax.loglog(n, [r["all_pairs"] * pair_s for r in rows], "x--", label="verify all pairs N(N-1)/2")
    ref = n * np.log2(np.maximum(n, 2))
    ax.loglog(n, s[-1] * ref / ref[-1], ":", color="grey", label="N log N (through the last point)")
    ax.set_xlabel("sessions N")
    ax.set_ylabel("seconds")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8)
    per = rows[-1]["keyframes"] / rows[-1]["sessions"]
    ax.set_title(f"vslam map: overlap search vs verifying all pairs ({per:.1f} keyframes / session)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("result", type=Path, help="a `vslam map` output folder of the fleet")
    p.add_argument("--sizes", type=int, nargs="+", default=[2, 4, 8, 16, 32, 64, 128, 256])
    p.add_argument("--repeats", type=int, default=3, help="best of this many timings per size")
    p.add_argument("--budget", type=int, default=4096,
                   help="posting entries per query (candidate_pairs' budget); 0: every word of a query")
    p.add_argument("--every-word", type=Path, help="results.json of a --budget 0 run, drawn beside on the plot")
    p.add_argument("--plot", type=Path)
    p.add_argument("-o", "--output", type=Path)
    args = p.parse_args(argv)
    doc = json.loads((args.result / "sessions.json").read_text())
    pair_s = statistics.mean(c["task_s"] for c in doc["candidates"] if c.get("task_s"))
    rows = []
    for n in args.sizes:
        rows.append(measure(args.result, n, args.repeats, args.budget))
        print(json.dumps(rows[-1]), file=sys.stderr)
    if args.output:
        args.output.write_text(json.dumps({"pair_task_s": pair_s, "rows": rows}, indent=1))
    if args.plot:
        every = [r["search_s"] for r in json.loads(args.every_word.read_text())["rows"]] if args.every_word else None
        plot(rows, pair_s, args.plot, every)
    print(f"mean pair-verification task: {pair_s:.2f} s")
    print("| N sessions | keyframes | queries | search s (read s) | pairs verified / all | "
          "verify candidates s | verify all pairs s |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['sessions']} | {r['keyframes']} | {r['queries']} | {r['search_s']} ({r['read_s']}) | "
              f"{r['candidate_pairs']} / {r['all_pairs']} | {r['candidate_pairs'] * pair_s:.0f} | "
              f"{r['all_pairs'] * pair_s:.0f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
