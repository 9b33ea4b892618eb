"""``vslam eval REF EST``: ATE, RPE (and the KITTI metric) of an estimated trajectory.

The reference (ground truth) comes first, as in ``evo_ape tum REF EST`` and TUM's
``evaluate_ate.py``. The alignment defaults to Sim(3) when EST was written by a monocular
``vslam run`` (its run folder's ``stats.json`` says ``sensor: mono``), SE(3) otherwise.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from vslam.errors import TrajectoryError

FORMATS = ["tum", "kitti", "euroc"]


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "eval", help="evaluate a trajectory against ground truth (ATE, RPE, KITTI)",
        description="Compare an estimated trajectory with a reference (ground truth): associate timestamps, "
                    "align (SE(3), Sim(3) or none) and print ATE, RPE and optionally the KITTI odometry metric. "
                    "The reference comes first, as in `evo_ape tum REF EST` and TUM's evaluate_ate.py. "
                    "KITTI files without a times file are associated by line index.",
    )
    p.add_argument("gt", metavar="REF", help="reference (ground-truth) trajectory (TUM, KITTI or EuRoC CSV; detected)")
    p.add_argument("est", metavar="EST", help="estimated trajectory")
    p.add_argument("--align", choices=["se3", "sim3", "none", "scale", "origin"],
                   help="alignment of the estimate onto the reference (default: sim3 when EST comes from a "
                        "monocular vslam run, whose scale is arbitrary; se3 otherwise)")
    p.add_argument("--align-first", type=int, metavar="N", help="estimate the alignment from the first N matched poses")
    p.add_argument("--est-format", choices=FORMATS, help="format of EST (default: detected)")
    p.add_argument("--gt-format", choices=FORMATS, help="format of GT (default: detected)")
    p.add_argument("--est-times", help="times file for a KITTI-format EST")
    p.add_argument("--gt-times", help="times file for a KITTI-format GT")
    p.add_argument("--max-diff", type=float, default=0.01, help="max timestamp difference in s (default 0.01)")
    p.add_argument("--offset", type=float, default=0.0, help="seconds added to EST timestamps (default 0)")
    p.add_argument("--by-index", action="store_true", help="pair poses by index instead of timestamps")
    p.add_argument("--duplicates", choices=["error", "keep-last"],
                   help="repeated timestamps: fail or keep the last pose, as the TUM tools do (default: the "
                        "reference keeps the last with a warning, as evo does; the estimate fails)")
    p.add_argument("--delta", type=float, default=1, help="RPE step (default 1)")
    p.add_argument("--delta-unit", choices=["frames", "m"], default="frames", help="unit of --delta")
    p.add_argument("--all-pairs", action="store_true", help="RPE over all pairs, not consecutive ones")
    p.add_argument("--kitti", action="store_true", help="also compute the KITTI odometry metric")
    p.add_argument("--lengths", type=float, nargs="+", metavar="M",
                   help="KITTI segment lengths in m (default 100 200 ... 800; e.g. 5 10 20 for short runs)")
    p.add_argument("--body-to-cam", metavar="SENSOR.yaml|none",
                   help="a EuRoC body-frame reference (state_groundtruth_estimate0, detected) is converted to the "
                        "camera with the T_BS of this sensor.yaml (default: mav0/cam0/sensor.yaml beside it); "
                        "none: compare it as it is")
    p.add_argument("--json", metavar="OUT.json", help="write all numbers to a JSON file")
    p.add_argument("--plot", metavar="OUT.png", help="write a plot (top view and ATE along time)")
    p.set_defaults(func=run)
    return p


def monocular_run(est_path: str | Path) -> bool:
    """Whether ``est_path`` lies in a run folder whose ``stats.json`` (or ``config.yaml``) says the
    run was monocular."""
    folder = Path(est_path).resolve().parent
    stats = folder / "stats.json"
    if stats.is_file():
        try:
            return json.loads(stats.read_text()).get("sensor") == "mono"
        except (OSError, ValueError, AttributeError):
            return False
    cfg = folder / "config.yaml"
    if cfg.is_file():
        try:
            import yaml

            data = yaml.safe_load(cfg.read_text())
        except (OSError, ValueError, yaml.YAMLError):
            return False
        return isinstance(data, dict) and data.get("sensor") == "mono"
    return False


def _body_to_camera(args: argparse.Namespace):
    """The conversion of a EuRoC body-frame reference to the camera
    (:func:`vslam.datasets.gt_frames.body_frame_reference`), or None: not one, ``--body-to-cam
    none``, or the estimate is body-frame too."""
    from vslam.datasets.gt_frames import body_frame_reference, is_euroc_body_gt

    choice = args.body_to_cam
    if (choice or "").strip().lower() == "none" or args.gt_format not in (None, "euroc") or is_euroc_body_gt(args.est):
        return None
    return body_frame_reference(args.gt, choice)


def run(args: argparse.Namespace) -> int:
    from vslam.eval.evaluate import evaluate_files
    from vslam.outputs import atomic_write_text, check_output_file, refuse_inputs, same_path, strict_json

    run_files = [Path(args.est).resolve().parent / n for n in ("stats.json", "config.yaml")]  # monocular_run reads them
    inputs = (args.gt, args.est, args.gt_times, args.est_times, args.body_to_cam,
              *[p for p in run_files if p.is_file()])
    for out_arg, what in ((args.json, "--json file"), (args.plot, "--plot file")):
        if out_arg:
            refuse_inputs(out_arg, inputs, what)  # never write the report over a trajectory
            check_output_file(out_arg, what)  # refuse a folder before the work, not after printing
    if args.json and args.plot and same_path(args.json, args.plot):
        raise TrajectoryError(f"{args.json}: given as both --json and --plot; choose two files")
    align, why = args.align, "as asked"
    if align is None:
        mono = monocular_run(args.est)
        align = "sim3" if mono else "se3"
        why = ("default for a monocular run (its scale is arbitrary)" if mono
               else "default; pass --align sim3 for a monocular estimate")
    dup = args.duplicates.replace("-", "_") if args.duplicates else None
    body = _body_to_camera(args)
    overrides = {}
    if args.by_index:
        overrides["by_index"] = True
    result = evaluate_files(
        args.est, args.gt, est_format=args.est_format, gt_format=args.gt_format,
        est_times=args.est_times, gt_times=args.gt_times, duplicates=dup or "error",
        gt_duplicates=dup or "keep_last", gt_T_right=body.T_body_cam if body else None, align=align, align_first=args.align_first, max_diff=args.max_diff, offset=args.offset,
        rpe_delta=args.delta, rpe_delta_unit=args.delta_unit, rpe_all_pairs=args.all_pairs,
        kitti=args.kitti or bool(args.lengths), kitti_lengths=tuple(args.lengths) if args.lengths else None,
        **overrides,
    )
    if body is not None:
        print(body.line())
    print(result.summary())
    print(f"alignment {align}: {why}")
    if args.json:
        out = Path(args.json)
        if not out.parent.is_dir():
            raise TrajectoryError(f"{out}: cannot write the JSON, folder {out.parent} does not exist")
        atomic_write_text(check_output_file(out, "--json file"), strict_json(result.to_dict(), indent=2) + "\n")
        print(f"wrote {out}")
    if args.plot:
        from vslam.eval.plot import plot_evaluation

        print(f"wrote {plot_evaluation(result, args.plot)}")
    return 0
