"""``vslam bench SPEC.yaml --output DIR``: run a benchmark spec and write results.json/.md and plots."""
from __future__ import annotations

import argparse
import logging
import os
from dataclasses import replace
from pathlib import Path

log = logging.getLogger(__name__)


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "bench", help="run a benchmark spec (many sequences, repeated), locally or on Ray",
        description="Run every run of a benchmark spec `repeats` times; write DIR/results.json, "
                    "DIR/results.md (median and min-max per run), DIR/ate.png, DIR/fps.png and one "
                    "run folder per (run, repeat) in DIR/runs/<name>/<repeat>/. Relative data paths "
                    "in the spec resolve against the spec's folder; ${VARS} are expanded.",
    )
    p.add_argument("spec", help="benchmark spec (YAML), e.g. benchmarks/smoke.yaml")
    p.add_argument("--output", "-o", required=True, help="output folder")
    p.add_argument("--executor", choices=["local", "ray"], default="local",
                   help="local: a process per run on this machine (default); ray: a Ray task per run")
    p.add_argument("--address", help="Ray cluster address (ray://host:10001, host:6379 or auto); "
                                     "default: start a local Ray")
    p.add_argument("--workers", type=int, default=None,
                   help="concurrent runs: local default 1 (comparable timings; 0 = in this process), "
                        "ray default: all CPUs of the local Ray")
    p.add_argument("--run", dest="runs", action="append", default=[], metavar="NAME",
                   help="only this run of the spec (repeatable)")
    p.add_argument("--repeats", type=int, help="override the spec's repeats for every run")
    p.add_argument("--dry-run", action="store_true",
                   help="write synthetic run folders instead of running SLAM (checks spec, harness, report)")
    p.add_argument("--baseline", choices=["orbslam3"], help="also run ORB-SLAM3 (optional GPL pyorbslam3)")
    p.add_argument("--vocabulary", help="DBoW2 text vocabulary (ORBvoc.txt) for --baseline orbslam3 "
                                         "(default: $PYORBSLAM3_VOCAB)")
    p.add_argument("--baseline-python", metavar="PY",
                   help="Python interpreter of a separate venv holding pyorbslam3 (the baseline runs there "
                        "in a subprocess; default: $VSLAM_ORBSLAM3_PYTHON, else this one if it has pyorbslam3)")
    p.add_argument("--baseline-pace", choices=["mono", "all", "none"], default="mono",
                   help="feed ORB-SLAM3 frames at the sensor rate for: monocular and inertial runs (default; "
                        "unpaced, its monocular mapping cannot keep up on 2 cores), all runs, or none")
    p.add_argument("--baseline-pace-rate", type=float, default=1.0, metavar="R",
                   help="paced ORB-SLAM3 runs get frames at R x the sensor rate (default 1; lower it on a "
                        "loaded machine, where ORB-SLAM3's monocular mapping falls behind and resets)")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    p.add_argument("--report", metavar="HTML", help="also write the HTML report of the benchmark here")
    p.set_defaults(func=run)
    return p


def _progress_line(row: dict, done: int, total: int) -> str:
    head = f"[{done}/{total}] {row['name']} #{row['repeat']}"
    if row.get("error"):
        return f"{head}: FAILED: {row['error']}"
    parts = [f"{row.get('tracked')}/{row.get('frames')} tracked"]
    if row.get("ate_rmse") is not None:
        parts.append(f"ATE {row['ate_rmse']:.4f} m")
    if row.get("fps") is not None:
        rt = f" ({row['realtime_factor']:.2f}x real time)" if row.get("realtime_factor") is not None else ""
        parts.append(f"{row['fps']:.1f} frames/s{rt}")
    if row.get("wall_s") is not None:
        parts.append(f"{row['wall_s']:.1f} s")
    return f"{head}: " + ", ".join(parts)


def run(args: argparse.Namespace) -> int:
    from vslam.bench.harness import make_executor, run_benchmark
    from vslam.bench.spec import MAX_REPEATS, load_spec, select_runs
    from vslam.errors import VslamError

    # the dry run checks the spec as the real run does (paths, settings); only the runner is a stand-in
    spec = load_spec(args.spec, check_paths=True, check_config=True, fake_keys=args.dry_run)
    spec = select_runs(spec, args.runs)
    if args.repeats is not None:
        if not 1 <= args.repeats <= MAX_REPEATS:
            raise VslamError(f"--repeats must be in [1, {MAX_REPEATS}], got {args.repeats}")
        spec = replace(spec, runs=tuple(replace(r, repeats=args.repeats) for r in spec.runs))
    workers = args.workers if args.workers is not None else (1 if args.executor == "local" else None)
    executor = make_executor(args.executor, workers=workers, address=args.address)
    runner = None
    if args.dry_run:
        from vslam.bench.fake import fake_run

        runner = fake_run
    baselines = {}
    if args.baseline == "orbslam3":
        from vslam.bench import orbslam3_baseline

        vocabulary = args.vocabulary or os.environ.get(orbslam3_baseline.VOCAB_ENV) or None
        baselines[orbslam3_baseline.NAME] = orbslam3_baseline.make_runner(
            vocabulary, python=args.baseline_python, pace=args.baseline_pace, pace_rate=args.baseline_pace_rate)
    elif args.vocabulary or args.baseline_python:
        raise VslamError("--vocabulary and --baseline-python are only used with --baseline orbslam3")
    n_jobs = spec.n_jobs * (1 + len(baselines))
    how = "" if workers is None else f" ({workers} worker{'' if workers == 1 else 's'})"
    print(f"benchmark {args.spec}: {len(spec.runs)} runs, {n_jobs} jobs, executor {args.executor}{how} "
          f"-> {args.output}", flush=True)

    def on_result(row: dict, done: int, total: int) -> None:
        print(_progress_line(row, done, total), flush=True)

    result = run_benchmark(spec, args.output, executor=executor, runner=runner, on_result=on_result,
                           baselines=baselines, plots=not args.no_plots)
    print(Path(result.files["md"]).read_text())
    if args.report:
        from vslam.report.html import write_report

        print(f"report: {write_report(result.output_dir, args.report)}")
    print(f"results in {result.output_dir} ({result.n_failed} of {len(result.rows)} runs failed)"
          if result.n_failed else f"results in {result.output_dir}")
    return 1 if result.n_failed else 0
