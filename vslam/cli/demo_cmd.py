"""``vslam demo [slam|drift] --output DIR``: render the built-in synthetic sequence and show its ground truth.

For now ``slam`` renders the default synthetic room sequence (RGB-D + stereo, TUM layout) to
``DIR/sequence/`` and plots its ground-truth path from above to ``DIR/ground_truth.png``; running
SLAM on it comes later. ``drift`` is not available yet.
"""
from __future__ import annotations

import argparse
import logging
from pathlib import Path

from vslam.errors import VslamError

log = logging.getLogger(__name__)

DEMOS = ("slam", "drift")


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "demo", help="run the built-in demo on a synthetic sequence",
        description="Render the built-in synthetic room sequence (exact ground truth, no download) "
                    "and show what vslam does with it.",
    )
    p.add_argument("which", nargs="?", choices=DEMOS, default="slam",
                   help="slam: render the sequence and plot its ground truth (default); drift: not available yet")
    p.add_argument("--output", "-o", default="demo_output", help="output folder (default: demo_output)")
    p.add_argument("--frames", type=int, default=300, help="number of frames to render (default 300)")
    p.add_argument("--seed", type=int, default=0, help="noise seed (default 0)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)
    return p


def render_demo_sequence(output: str | Path, n_frames: int = 300, seed: int = 0, progress: bool = True) -> dict:
    """Render the demo sequence to ``output/sequence`` and plot ``output/ground_truth.png``.

    Returns the paths written: ``{"sequence": Path, "ground_truth_plot": Path}``.
    """
    from vslam.datasets.synthetic import SyntheticSequence, plot_ground_truth_topdown, render_sequence

    if n_frames < 2:
        raise VslamError(f"--frames must be at least 2, got {n_frames}")
    out = Path(output)
    config = demo_config(n_frames, seed)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=n_frames, desc="rendering", unit="frame")
    done = [0]

    def tick(n: int) -> None:
        if bar is not None:
            bar.update(n - done[0])
        done[0] = n

    try:
        seq_dir = render_sequence(out / "sequence", config, progress=tick)
    finally:
        if bar is not None:
            bar.close()
    plot = plot_ground_truth_topdown(
        SyntheticSequence(config).T_world_cam, out / "ground_truth.png", title="synthetic room, ground truth"
    )
    return {"sequence": seq_dir, "ground_truth_plot": plot}


def demo_config(n_frames: int = 300, seed: int = 0):
    """The demo's sequence: one loop round the room, mild sensor noise, RGB-D and stereo."""
    from vslam.datasets.synthetic import SyntheticConfig

    return SyntheticConfig(
        n_frames=n_frames, seed=seed, pixel_noise=2.0, depth_noise=0.002, depth_noise_model="proportional",
        missing_depth=0.02, missing_depth_mode="blobs",
    )


def run(args: argparse.Namespace) -> int:
    if args.which == "drift":
        raise VslamError("the 'drift' demo is not available yet; run 'vslam demo slam' (the default)")
    paths = render_demo_sequence(args.output, args.frames, args.seed, progress=not args.no_progress)
    print(f"synthetic sequence ({args.frames} frames, TUM layout, RGB-D + stereo): {paths['sequence']}")
    print(f"ground-truth path (top view): {paths['ground_truth_plot']}")
    print(f"run SLAM on it with: vslam run {paths['sequence']} --output {Path(args.output) / 'run'}")
    return 0
