"""The built-in demos, runnable on a fresh machine with no data download.

* :func:`slam_demo`: render the synthetic room sequence (exact ground truth) to disk in TUM
  layout, run the full SLAM pipeline on it through the real reader, evaluate the trajectory
  against the ground truth and plot both.
* :func:`drift_demo`: the seed's drift demonstration (noisy incremental odometry round a circle,
  closed by one loop constraint and a pose-graph optimization).
"""
from __future__ import annotations

import logging
from pathlib import Path

from vslam.errors import VslamError

log = logging.getLogger(__name__)


def demo_sequence_config(n_frames: int = 200, seed: int = 0, stereo: bool = False):
    """The demo's sequence: one loop round the room with mild sensor noise (RGB-D; stereo optional)."""
    from vslam.datasets.synthetic import SyntheticConfig

    return SyntheticConfig(
        n_frames=n_frames, seed=seed, pixel_noise=2.0, depth_noise=0.002, depth_noise_model="proportional",
        missing_depth=0.02, missing_depth_mode="blobs", stereo=stereo,
    )


def render_demo_sequence(output: str | Path, n_frames: int = 200, seed: int = 0, progress: bool = True,
                         stereo: bool = False) -> dict:
    """Render the demo sequence to ``output/sequence`` and plot ``output/ground_truth.png``."""
    from vslam.datasets.synthetic import SyntheticSequence, plot_ground_truth_topdown, render_sequence

    if n_frames < 2:
        raise VslamError(f"--frames must be at least 2, got {n_frames}")
    out = Path(output)
    config = demo_sequence_config(n_frames, seed, stereo)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=n_frames, desc="rendering", unit="frame", leave=False)
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


def slam_demo(output: str | Path, n_frames: int = 200, seed: int = 0, sensor: str = "rgbd",
              overrides: tuple[str, ...] = (), progress: bool = True) -> dict:
    """Render, run SLAM, evaluate. Returns the run stats plus the paths written."""
    from vslam.api import run_path
    from vslam.datasets import open_dataset
    from vslam.eval import evaluate_trajectories
    from vslam.eval.plot import plot_evaluation

    out = Path(output)
    paths = render_demo_sequence(out, n_frames, seed, progress, stereo=(sensor == "stereo"))
    result = run_path(paths["sequence"], out / "run", sensor=sensor, overrides=overrides, progress=progress)
    gt = open_dataset(paths["sequence"], sensor=sensor).ground_truth()
    if len(result.trajectory) < 3:
        raise VslamError(f"the demo tracked only {len(result.trajectory)} frames; see {out / 'run'}")
    ev = evaluate_trajectories(result.trajectory, gt, align="sim3" if sensor == "mono" else "se3")
    plot = plot_evaluation(ev, out / "run" / "trajectory.png", title=f"vslam demo ({sensor})")
    return {**paths, "run": out / "run", "trajectory_plot": plot, "stats": result.stats,
            "ate_rmse": ev.ate.rmse, "matched_poses": ev.matched_poses}


def drift_demo(output: str | Path, noise: float = 1.0, seed: int = 0) -> dict:
    """Noisy odometry round a circle, one loop constraint at the end, pose-graph optimization.

    Returns end-point drift and ATE before/after the correction, and ``plot`` (the PNG path).
    """
    from vslam.backend.drift_demo import run_drift_demo

    if not noise > 0:
        raise VslamError(f"--noise must be > 0, got {noise}")
    res = run_drift_demo(output, noise=noise, seed=seed)
    res["plot"] = res.get("plot") or res.get("png") or Path(output) / "drift_demo.png"
    return res
