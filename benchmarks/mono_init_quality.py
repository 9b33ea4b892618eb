"""How good is a young monocular map? Many cold starts of one sequence, each scored on its first
frames (issue #24: the re-initialized map's scale collapse).

A whole monocular run is chaotic: one changed keyframe early on changes everything after it, so a
setting that helps one start or one dropped-frames scenario hurts the next (benchmarks/RESULTS.md,
round 8). This scores only what a setting does to the first seconds of a map, over many starts:
for each start frame ``s`` in ``START:STOP:STEP`` a fresh :class:`vslam.system.System` tracks from
``s`` until ``--frames`` frames have a pose (at most ``2 * --frames + 60`` frames), and the posed
frames are compared with the ground truth:

- ``delay``: frames from ``s`` to the first posed frame (the two-view initialization's wait);
- ``rel``: Sim(3)-aligned ATE over the posed frames / the ground-truth path length over them;
- ``tdir_deg``: angle between the estimated and the true translation of the last posed frame
  relative to the first (a wrong two-view decomposition or a bas-relief flip shows as ~90-180 deg);
- ``drift``: the Sim(3) scale of the last 30 posed frames over that of the first 30 (1: no scale
  drift; a collapsing young map gives 0.1-0.3 or 3-10).

    python benchmarks/mono_init_quality.py ../shared/data/7scenes_redkitchen --starts 0:1000:7 \
        --workers 2 -o /tmp/initq.json [--set frontend.init.rotation_parallax_deg=0.6 ...]

Prints one markdown line of medians, means, 90th percentiles and counts of bad starts.
"""
from __future__ import annotations

import argparse
import json
import logging
import math
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

log = logging.getLogger("mono_init_quality")
WINDOW = 30  # frames of each end whose Sim(3) scales give the drift


def score_start(data: str, start: int, frames: int, overrides: list[str]) -> dict:
    """Track ``data`` (monocular) from ``start`` until ``frames`` frames have a pose; the scores
    of the module docstring (``rel``, ``tdir_deg``, ``drift`` absent when too few frames)."""
    from vslam.api import resolve_config
    from vslam.datasets import open_dataset
    from vslam.eval import evaluate_trajectories
    from vslam.system import System
    from vslam.trajectory import Trajectory

    ds = open_dataset(data, sensor="mono")
    gt = ds.ground_truth()
    gt_pose = {round(float(t), 6): T for t, T in zip(gt.timestamps, gt.T_world_cam)}
    system = System(resolve_config(None, list(overrides)), ds.camera, sensor="mono")
    stamps, T_world_cam, first = [], [], None
    for i in range(start, min(start + 2 * frames + 60, len(ds))):
        frame = ds[i]
        result = system.track(frame)
        if result.T_world_cam is None or round(float(frame.timestamp), 6) not in gt_pose:
            continue
        first = i if first is None else first
        stamps.append(frame.timestamp)
        T_world_cam.append(result.T_world_cam)
        if len(stamps) >= frames:
            break
    row: dict = {"start": start, "delay": None if first is None else first - start, "posed": len(stamps)}
    if len(stamps) < 10:
        return row

    def aligned(sel: slice):
        tr = Trajectory(np.array(stamps[sel]), np.array(T_world_cam[sel]))
        return evaluate_trajectories(tr, gt, align="sim3")

    whole = aligned(slice(None))
    p_gt = np.array([gt_pose[round(float(t), 6)][:3, 3] for t in stamps])
    path = float(np.sum(np.linalg.norm(np.diff(p_gt, axis=0), axis=1)))
    rel_est = np.linalg.inv(T_world_cam[0]) @ T_world_cam[-1]
    rel_gt = np.linalg.inv(gt_pose[round(float(stamps[0]), 6)]) @ gt_pose[round(float(stamps[-1]), 6)]
    a, b = rel_est[:3, 3], rel_gt[:3, 3]
    cos = float(a @ b / max(np.linalg.norm(a) * np.linalg.norm(b), 1e-12))
    row.update(rel=float(whole.ate.rmse) / max(path, 1e-9), tdir_deg=math.degrees(math.acos(min(1.0, max(-1.0, cos)))))
    if len(stamps) >= 2 * WINDOW:
        row["drift"] = float(aligned(slice(-WINDOW, None)).alignment.s / aligned(slice(0, WINDOW)).alignment.s)
    return row


def summary(rows: list[dict]) -> str:
    """One markdown table row: starts, posed, rel median / mean / p90, bad counts, delay, drift."""
    ok = [r for r in rows if "rel" in r]
    rel = np.array([r["rel"] for r in ok])
    tdir = np.array([r["tdir_deg"] for r in ok])
    delay = np.array([r["delay"] for r in ok])
    drift = np.array([abs(math.log(r["drift"])) for r in ok if "drift" in r])
    return (f"| {len(rows)} | {len(ok)} | {np.median(rel):.3f} / {rel.mean():.3f} / {np.percentile(rel, 90):.3f} "
            f"| {(rel > 0.05).sum()} | {(tdir > 45).sum()} | {np.median(delay):.0f} / {delay.mean():.1f} "
            f"| {(drift > math.log(1.5)).sum()} / {(drift > math.log(2)).sum()} of {len(drift)} |")


HEADER = ("| starts | scored | rel median / mean / p90 | rel > 0.05 | tdir > 45 deg | delay median / mean "
          "| drift beyond 1.5x / 2x |\n|---|---|---|---|---|---|---|")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("data", help="a monocular sequence with ground truth")
    ap.add_argument("--starts", default="0:1000:7", help="START:STOP:STEP of the start frames")
    ap.add_argument("--frames", type=int, default=100, help="posed frames scored per start")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="configuration override")
    ap.add_argument("-o", "--output", type=Path, help="write the per-start rows as JSON")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    logging.getLogger("vslam").setLevel(logging.ERROR)
    a, b, step = (int(x) for x in args.starts.split(":"))
    starts = list(range(a, b, step))
    with ProcessPoolExecutor(max_workers=max(args.workers, 1)) as pool:
        rows = list(pool.map(score_start, [args.data] * len(starts), starts, [args.frames] * len(starts),
                             [args.set] * len(starts)))
    if args.output:
        args.output.write_text(json.dumps({"data": args.data, "set": args.set, "rows": rows}, indent=1))
    log.info("%s\n%s", HEADER, summary(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
