"""``vslam gt DATASET -o gt.txt``: the ground truth a run over DATASET is evaluated against, as TUM.

The poses are those :func:`vslam.datasets.ground_truth.resolve_ground_truth` gives a run (at the
frame timestamps, of the camera whose images the frames carry: TUM rgb, KITTI cam0, EuRoC cam0
(rectified for stereo), 7-Scenes' camera), so ``evo_ape tum gt.txt RUN/trajectory.txt`` compares
like with like.
"""
from __future__ import annotations

import argparse


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "gt", help="write the ground truth a run would use, as a TUM file",
        description="Write the ground truth that `vslam run` evaluates a sequence against (TUM, KITTI, EuRoC "
                    "cam0, 7-Scenes, a bag's groundtruth.txt) in TUM format, at the frame timestamps and in "
                    "the camera frame of the run's trajectory.txt, e.g. to feed evo.",
    )
    p.add_argument("path", help="sequence folder (or ROS bag)")
    p.add_argument("--output", "-o", required=True, help="TUM file to write")
    p.add_argument("--sensor", choices=["mono", "stereo", "rgbd"],
                   help="as `vslam run` (default: rgbd, else stereo, else mono); EuRoC stereo gives the rectified "
                        "left camera, mono the raw cam0")
    p.add_argument("--dataset", help="force the format: tum, kitti, euroc, 7scenes, rosbag")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from vslam.api import open_sequence
    from vslam.datasets.ground_truth import dataset_gt_file
    from vslam.datasets.gt_frames import ground_truth_of
    from vslam.errors import OutputError
    from vslam.outputs import check_output_file, lies_inside, refuse_inputs
    from vslam.trajectory import write_tum

    out = Path(args.output)
    ds, _sensor, _stop = open_sequence(args.path, args.dataset, args.sensor, 0, None)
    refuse_inputs(out, (args.path, dataset_gt_file(ds)), "ground truth")
    if out.exists() and lies_inside(out, args.path):
        raise OutputError(f"{out}: is a file of the sequence {args.path}; write the ground truth elsewhere")
    check_output_file(out, "ground truth")
    traj, file, frame = ground_truth_of(ds)
    write_tum(out, traj)  # atomic (vslam.outputs.atomic_write_text)
    print(f"{len(traj)} poses of {len(ds)} frames from {file} (frame {frame}) -> {out}")
    return 0
