"""``vslam report RUN_OR_BENCH_DIR --output report.html``: a self-contained HTML report."""
from __future__ import annotations

import argparse


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "report", help="write a self-contained HTML report of a run or benchmark folder",
        description="One HTML page with every image embedded (no external URLs). For a `vslam run` "
                    "folder: summary, trajectory vs ground truth from above with loop closures, error "
                    "along the path, time per stage, sparse map. For a `vslam bench` folder: the "
                    "results table, plots and a report per run (written as runs/<name>/<repeat>/report.html).",
    )
    p.add_argument("folder", help="a `vslam run` output folder or a `vslam bench` output folder")
    p.add_argument("--output", "-o", required=True, help="HTML file to write")
    p.add_argument("--no-run-reports", action="store_true",
                   help="bench folders: do not write a report per run")
    p.add_argument("--gt", metavar="FILE|none",
                   help="run folders: ground truth to compare with (TUM, KITTI or EuRoC trajectory; default: "
                        "groundtruth.txt in the folder, else the one the run used); none: no ground truth")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from vslam.report.html import write_report

    if (Path(args.folder) / "sessions.json").is_file():  # a `vslam map` output folder (issue #26)
        from vslam.report.multisession import write_multisession_report

        print(f"report: {write_multisession_report(args.folder, args.output)}")
        return 0
    path = write_report(args.folder, args.output, run_reports=not args.no_run_reports, gt=args.gt)
    print(f"report: {path}")
    return 0
