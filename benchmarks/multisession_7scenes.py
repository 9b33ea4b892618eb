"""Issue #26's real-data goal: 7-Scenes redkitchen cut into 5 overlapping RGB-D sessions
(``benchmarks/multisession_7scenes.yaml``) mapped by ``vslam map`` into one map; ATE over every
frame of every session after ONE SE(3) alignment to the ground truth (goal < 0.05 m), per session
under that alignment, and each session aligned on its own (what the sessions alone give). Then the
same result again with ``--no-pose-graph`` (the finished sessions and pair verifications reused)
to measure what the pose graph over every overlap does.

    python benchmarks/multisession_7scenes.py -o /tmp/ms7 [--workers 2]

Writes ``DIR/results.json`` and prints a markdown table.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

SPEC = Path(__file__).with_name("multisession_7scenes.yaml")


def evaluate(out: Path) -> dict:
    from vslam.datasets import open_dataset
    from vslam.eval.joint import joint_ate
    from vslam.trajectory import read_tum

    doc = json.loads((out / "sessions.json").read_text())
    comp = [s for s in doc["sessions"] if s.get("component") == 0]
    gt = open_dataset(comp[0]["spec"]["data"], sensor="rgbd").ground_truth()
    est = {s["name"]: read_tum(s["trajectory"]) for s in comp}
    joint = joint_ate(est, {n: gt for n in est})
    alone = {n: round(joint_ate({n: read_tum(Path(s["folder"]) / "trajectory.txt")}, {n: gt}).rmse, 4)
             for n, s in ((s["name"], s) for s in comp)}
    c0 = doc["component_maps"][0]
    return {"components": doc["components"], "frames": joint.frames, "ate_m": round(joint.rmse, 4),
            "per_session_m": {k: round(v, 4) for k, v in joint.per_name.items()}, "alone_m": alone,
            "pose_graph": c0.get("pose_graph"), "global_ba": c0.get("global_ba"), "timing": doc["timing"],
            "overlaps": [[e["a"], e["b"], e["inliers"], e["in_tree"]] for e in doc["overlaps"]]}


def run(out: Path, workers: int, extra: list[str]) -> dict:
    cmd = [sys.executable, "-m", "vslam", "map", str(SPEC), "-o", str(out), "--workers", str(workers), *extra]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env={**os.environ})
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed:\n{proc.stderr[-3000:]}")
    return {"wall_s": round(time.perf_counter() - t0, 1), **evaluate(out)}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("-o", "--output", type=Path, required=True)
    p.add_argument("--workers", type=int, default=2)
    args = p.parse_args(argv)
    rows = {"pose graph + global BA": run(args.output, args.workers, []),
            "global BA only (--no-pose-graph)": run(args.output, args.workers, ["--no-pose-graph"])}
    (args.output / "results.json").write_text(json.dumps(rows, indent=1))
    print("| variant | components | frames | ATE one SE(3) m | per session (same alignment) m | wall s |")
    print("|---|---|---|---|---|---|")
    for name, r in rows.items():
        print(f"| {name} | {' + '.join(str(len(c)) for c in r['components'])} | {r['frames']} | {r['ate_m']} | "
              f"{' / '.join(str(v) for v in r['per_session_m'].values())} | {r['wall_s']} |")
    first = next(iter(rows.values()))
    print("sessions alone (each aligned on its own): " + ", ".join(f"{k} {v}" for k, v in first["alone_m"].items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
