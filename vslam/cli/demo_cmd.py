"""``vslam demo [slam|drift] --output DIR``: the built-in demos (no download, no ../shared).

``slam`` (default) renders the synthetic room sequence with exact ground truth, runs SLAM on it
and prints the ATE; ``drift`` shows odometry drift removed by a loop closure on a pose graph.
"""
from __future__ import annotations

import argparse
import logging
from pathlib import Path

log = logging.getLogger(__name__)

DEMOS = ("slam", "drift")


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "demo", help="run the built-in demo on a synthetic sequence",
        description="Render the built-in synthetic room sequence (exact ground truth, no download), "
                    "run SLAM on it and evaluate; or show loop-closure drift correction.",
    )
    p.add_argument("which", nargs="?", choices=DEMOS, default="slam",
                   help="slam: render, run SLAM, evaluate (default); drift: loop closure removes drift")
    p.add_argument("--output", "-o", default="demo_output", help="output folder (default: demo_output)")
    p.add_argument("--frames", type=int, default=150, help="frames to render for the slam demo (default 150)")
    p.add_argument("--sensor", choices=["rgbd", "stereo", "mono"], default="rgbd", help="slam demo sensor")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a setting for the slam demo (repeatable)")
    p.add_argument("--noise", type=float, default=1.0, help="drift demo: odometry noise level (default 1.0)")
    p.add_argument("--seed", type=int, default=0, help="noise seed (default 0)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    from vslam import demo

    if args.which == "drift":
        res = demo.drift_demo(args.output, noise=args.noise, seed=args.seed)
        print(f"end-point drift: {res['end_drift_before']:.3f} m before loop closure, "
              f"{res['end_drift_after']:.3f} m after")
        print(f"ATE: {res['ate_before']:.3f} m before, {res['ate_after']:.3f} m after")
        print(f"plot: {res['plot']}")
        return 0
    from vslam.cli.common import compile_notice

    with compile_notice():
        res = demo.slam_demo(args.output, args.frames, args.seed, sensor=args.sensor,
                             overrides=tuple(args.overrides), progress=not args.no_progress)
    s = res["stats"]
    print(f"synthetic sequence ({args.frames} frames, TUM layout): {res['sequence']}")
    print(f"tracked {s['tracked']}/{s['frames']} frames ({s.get('lost', 0)} lost), {s.get('keyframes', 0)} keyframes, "
          f"{s.get('map_points', 0)} map points, {s['fps']:.1f} frames/s")
    print(f"ATE RMSE {res['ate_rmse']:.4f} m over {res['matched_poses']} poses (SE(3) alignment)")
    print(f"plots: {res['ground_truth_plot']}, {res['trajectory_plot']}")
    print(f"run folder: {res['run']}")
    return 0
