"""``vslam merge MAP_A MAP_B -o OUT``: merge two saved maps (B joined into A's frame)."""
from __future__ import annotations

import argparse
from pathlib import Path


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "merge", help="merge two saved maps into one",
        description="Merge the map of MAP_B into the map of MAP_A (both `vslam run` output folders): the overlap "
                    "is found by place recognition and geometric verification, B is aligned (SE(3); Sim(3) for "
                    "monocular maps), appended, and the seam welded (point fusion, local BA, global BA). Writes "
                    "OUT/map/, OUT/keyframes.txt (TUM, in MAP_A's frame), OUT/sparse.ply, OUT/merge.png (both maps' "
                    "keyframes, the seam, the alignment's inliers and residual) and OUT/stats.json. "
                    "Maps that do not overlap are an error.",
    )
    p.add_argument("map_a", help="the reference map: a `vslam run` output folder (containing map/)")
    p.add_argument("map_b", help="the map joined into it")
    p.add_argument("--output", "-o", required=True, help="output folder")
    p.add_argument("--config", help="YAML file with settings (default: MAP_A/config.yaml)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override one setting, e.g. --set loop.closing.min_inliers=30 (repeatable)")
    p.add_argument("--no-global-ba", action="store_true", help="weld with the seam's local BA only")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    from vslam.merge import MergeOptions, merge_paths

    result = merge_paths(args.map_a, args.map_b, args.output, config=args.config, overrides=args.overrides,
                         options=MergeOptions(global_ba=not args.no_global_ba))
    s = result.stats
    print(f"merged {s['keyframes_b']} keyframes of B into {s['keyframes_a']} of A: {s['seam_keyframes']} seam "
          f"keyframes, scale {s['scale']:.4f}, {s['fused_points']} points fused, {s['good_keyframes']} keyframes, "
          f"{s['points']} points")
    print(f"alignment: {s['alignment_inliers']} of {s['alignment_correspondences']} seam correspondences inliers, "
          f"RMS residual {s['alignment_residual']:.4f} {'(map A units)' if s.get('sensor') == 'mono' else 'm'}"
          + (f"; figure {s['figure']}" if s.get("figure") else ""))
    print(f"results in {Path(args.output)}")
    return 0
