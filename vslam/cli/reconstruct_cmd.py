"""``vslam reconstruct RUN_DIR``: dense TSDF mesh and point cloud of a `vslam run` output folder."""
from __future__ import annotations

import argparse
import json


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "reconstruct", help="dense mesh and point cloud (TSDF) of a run folder",
        description="Reopen the sequence of a `vslam run` folder (rgbd or stereo), fuse its keyframes (or every "
                    "N-th tracked frame) along the estimated poses into a TSDF volume and write RUN_DIR/mesh.ply "
                    "(triangle mesh) and RUN_DIR/dense.ply (point cloud). Needs the dense extra: "
                    "pip install 'vslam[dense]'.",
    )
    p.add_argument("run_dir", help="output folder of `vslam run` (with stats.json and keyframes.txt)")
    p.add_argument("--voxel", type=float, metavar="M",
                   help="voxel size in metres (default 0.01 for rgbd; depth range / 400 for stereo)")
    p.add_argument("--every", type=int, metavar="N",
                   help="fuse every N-th tracked frame of trajectory.txt instead of the keyframes")
    p.add_argument("--max-depth", type=float, metavar="M",
                   help="ignore depth beyond M metres (default 4 for rgbd; 8 px disparity for stereo)")
    p.add_argument("--sdf-trunc", type=float, metavar="M", help="TSDF truncation in metres (default 4 voxels)")
    p.add_argument("--max-frames", type=int, metavar="N", help="fuse at most N frames, evenly spaced")
    p.add_argument("--output", "-o", help="write the PLY files here instead of RUN_DIR")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    from vslam.api import progress_bar
    from vslam.reconstruction import reconstruct_run

    res = reconstruct_run(
        args.run_dir, voxel_size=args.voxel, every=args.every, depth_max=args.max_depth, sdf_trunc=args.sdf_trunc,
        max_frames=args.max_frames, output_dir=args.output, progress=progress_bar(not args.no_progress),
    )
    if args.json:
        print(json.dumps(res, indent=2))
        return 0
    ext = " x ".join(f"{v:.2f}" for v in res["extent_m"])
    print(f"fused {res['frames_fused']} frames ({res['poses_from']}, voxel {res['voxel_size']:.3f} m, "
          f"depth <= {res['depth_max']:.1f} m) in {res['total_s']:.1f} s")
    print(f"mesh: {res['vertices']} vertices, {res['triangles']} triangles, extent {ext} m -> {res['mesh']}")
    print(f"point cloud: {res['points']} points -> {res['dense']}")
    return 0
