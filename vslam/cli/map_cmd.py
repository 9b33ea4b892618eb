"""``vslam map INPUTS... -o OUT [--executor local|ray] [--address ADDR] [--workers N]``: many
recordings tracked as parallel tasks, their overlaps found and verified, merged into one map per
connected component (:mod:`vslam.multisession`)."""
from __future__ import annotations

import argparse
import sys


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "map", help="map many recordings at once and merge them",
        description="Track every session (recordings, or one YAML file with `sessions: [{name, data, sensor, camera, "
                    "start_frame, max_frames}]`) as its own task into OUT/sessions/<name>/ (a finished one is "
                    "reused), find overlapping sessions through one bag-of-words index over all their keyframes, "
                    "verify the candidate pairs geometrically (one task each), merge each connected component "
                    "pairwise up the spanning tree of its strongest overlaps (parallel rounds, one task per merge), "
                    "then optimize it once (a pose graph over every verified overlap, a global BA). "
                    "Writes OUT/map/ (largest component; others in "
                    "OUT/components/<i>/), OUT/trajectories/<name>.txt (TUM, in the component's common frame), "
                    "OUT/sparse.ply, OUT/sessions.json (sessions, overlaps, components) and OUT/report.html.",
    )
    p.add_argument("inputs", nargs="+", metavar="INPUT",
                   help="a recording (any path `vslam run` reads) or one sessions YAML")
    p.add_argument("--output", "-o", help="output folder (default with --map: that folder)")
    p.add_argument("--map", dest="map_dir", metavar="OUT",
                   help="add INPUTS to an earlier `vslam map` result: its components are kept (not tracked, "
                        "searched or merged again); only the new recordings are tracked, their overlaps searched "
                        "and verified, and they are merged into the existing maps")
    p.add_argument("--executor", choices=("local", "ray"), default="local",
                   help="local process pool (default) or Ray tasks")
    p.add_argument("--address", help="Ray cluster address (default: start a local Ray)")
    p.add_argument("--workers", type=int, help="parallel tasks (local processes, or CPUs of the local Ray; "
                                               "default: CPU count; 0: local, in this process)")
    p.add_argument("--sensor", choices=("mono", "stereo", "rgbd"), help="sensor of sessions that do not name one")
    p.add_argument("--candidates", type=int, default=3, help="candidate partners verified per session (default 3)")
    p.add_argument("--no-pose-graph", action="store_true",
                   help="skip the pose graph over every verified overlap after the tree merge (the global BA "
                        "still runs); for comparison")
    p.add_argument("--no-report", action="store_true", help="do not write OUT/report.html")
    p.add_argument("--config", help="YAML file with settings for every session")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override one setting for every session (repeatable)")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    from vslam.errors import ConfigError
    from vslam.multisession import map_sessions

    if args.candidates < 1:
        raise ConfigError(f"--candidates must be >= 1, got {args.candidates}")
    inputs = args.inputs
    if args.map_dir:
        from pathlib import Path

        from vslam.multisession.sessions import parse_inputs, previous_sessions

        if args.output and Path(args.output).resolve() != Path(args.map_dir).resolve():
            raise ConfigError("--map adds sessions to that result in place: leave out -o or give the same folder")
        args.output = args.map_dir
        old = previous_sessions(args.map_dir)
        inputs = old + parse_inputs(args.inputs, args.sensor, taken={s.name for s in old})
    elif not args.output:
        raise ConfigError("the output folder is missing: -o OUT (or --map OUT to add to an earlier result)")
    result = map_sessions(inputs, args.output, executor=args.executor, workers=args.workers,
                          address=args.address, config=args.config, overrides=tuple(args.overrides),
                          sensor=args.sensor, candidates=args.candidates, pose_graph=not args.no_pose_graph,
                          incremental=bool(args.map_dir),
                          on_progress=lambda msg: print(msg, file=sys.stderr, flush=True))
    failed = [s for s in result["sessions"] if s["status"] != "ok"]
    comps = result["components"]
    print(f"{len(result['sessions']) - len(failed)} of {len(result['sessions'])} sessions mapped, "
          f"{len(result['overlaps'])} verified overlaps ({len(result['candidates'])} candidate pairs of "
          f"{result['index']['all_pairs']}), {len(comps)} component{'s' * (len(comps) != 1)}: "
          + "; ".join(", ".join(c) for c in comps))
    for s in failed:
        print(f"session {s['name']} failed: {s['error']}")
    for i, c in enumerate(result["component_maps"]):
        if c.get("error"):
            print(f"component {i} ({', '.join(c['sessions'])}): its map and trajectories failed: {c['error']}")
    if not args.no_report:
        from vslam.report.multisession import write_multisession_report

        try:  # a page never fails a finished map
            print(f"report: {write_multisession_report(args.output)}")
        except Exception as exc:  # noqa: BLE001
            print(f"report.html not written ({type(exc).__name__}: {exc}); `vslam report {args.output} -o PAGE.html` "
                  "retries", file=sys.stderr)
    print(f"results in {args.output} ({result['timing']['total_s']:.1f} s)")
    return 0 if comps else 1  # no session mapped: nothing to merge
