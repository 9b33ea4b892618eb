"""``vslam localize MAP_DIR PATH``: localize a sequence in a saved map; writes trajectory and stats."""
from __future__ import annotations

import argparse
import logging
from pathlib import Path

from vslam.cli.common import add_gt_argument, ate_line, compile_notice

log = logging.getLogger(__name__)


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "localize", help="localize a sequence in a saved map",
        description="Localize the frames of a sequence in a map saved by `vslam run` (its --output folder): "
                    "global relocalization from a cold start, then tracking against the fixed map. "
                    "Frames that cannot be localized are counted, not guessed.",
    )
    p.add_argument("map_dir", help="the folder a `vslam run` wrote (containing map/)")
    p.add_argument("path", help="sequence folder")
    p.add_argument("--output", "-o", required=True, help="output folder (trajectory.txt, stats.json)")
    p.add_argument("--sensor", choices=["mono", "stereo", "rgbd", "mono-inertial", "stereo-inertial", "rgbd-inertial"],
                   help="default: the map's sensor (an inertial one, in a visual-inertial map, predicts "
                        "each frame with the IMU and poses frames vision cannot localize for up to a second)")
    p.add_argument("--imu", metavar="FILE",
                   help="IMU samples for an inertial sensor on a sequence without them (EuRoC CSV columns: "
                        "t, w_xyz rad/s, a_xyz m/s^2), its calibration (Kalibr camchain-imucam.yaml, imu.yaml, or "
                        "ORB-SLAM3 settings) beside it")
    p.add_argument("--dataset", help="force the format: tum, kitti, euroc, 7scenes, folder")
    p.add_argument("--camera", metavar="FILE",
                   help="camera calibration of the sequence (any format `vslam run --camera` reads)")
    p.add_argument("--config", help="YAML file with settings")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override one setting, e.g. --set localize.min_inliers=40 (repeatable)")
    p.add_argument("--start-frame", type=int, default=0, help="first frame to localize")
    p.add_argument("--max-frames", type=int, help="stop after N frames")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_gt_argument(p)
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    from vslam.localize import localize_path

    with compile_notice():
        result = localize_path(
            args.map_dir, args.path, args.output, sensor=args.sensor, dataset=args.dataset,
            start_frame=args.start_frame, max_frames=args.max_frames, config=args.config, overrides=args.overrides,
            progress=not args.no_progress, camera=args.camera, gt=args.gt, imu=args.imu,
        )
    from vslam.localize import counts_line

    s = result.stats
    print(f"{counts_line(s)}, {s['fps']:.1f} frames/s, in the map of {s.get('map', args.map_dir)}")
    if ate_line(s):
        print(ate_line(s))
    print(f"results in {Path(args.output)}")
    return 0
