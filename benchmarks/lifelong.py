"""Lifelong mapping benchmark (issue #18 item 5): a map that grows with the place, not with time.

Drives the same rendered loop several times (RGB-D, default pipeline) and reports per lap the
keyframes added, the frames per second (wall and CPU), and the resident memory, plus the ATE of the whole run.

Run: ``python benchmarks/lifelong.py`` (the 3000-frame / 10-lap sequence of the issue, minutes) or
``python benchmarks/lifelong.py --frames 600 --laps 4`` (prints JSON). ``run_lifelong()`` returns
the same dict.
"""
from __future__ import annotations

import argparse
import json
import time

import numpy as np


def _rss_mb() -> float:
    """Resident memory of this process in MB (Linux ``/proc/self/statm``)."""
    import os

    with open("/proc/self/statm") as f:
        return round(int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20, 1)


def run_lifelong(n_frames: int = 3000, laps: int = 10, seed: int = 0, width: int = 640, height: int = 480,
                 overrides: tuple[str, ...] = (), rss_at: tuple[int, ...] = (300, 600)) -> dict:
    """Run the default RGB-D pipeline on ``laps`` laps of the synthetic loop; returns per-lap
    keyframes / fps, RSS at ``rss_at`` frames and at the end, and the ATE (SE(3)-aligned)."""
    from vslam.config import Config, load_config
    from vslam.datasets.synthetic import SyntheticConfig, SyntheticSequence
    from vslam.eval import evaluate_trajectories
    from vslam.system import System

    s = width / 640.0
    cfg = SyntheticConfig(n_frames=n_frames, laps=laps, pixel_noise=2, depth_noise=0.01,
                          depth_noise_model="proportional", seed=seed, width=width, height=height,
                          fx=525.0 * s, fy=525.0 * s, cx=(width - 1) / 2, cy=(height - 1) / 2)
    seq = SyntheticSequence(cfg)
    system = System(load_config(Config, None, list(overrides)), seq.camera, sensor="rgbd")
    per_lap = n_frames / laps
    lap_kfs = [0] * laps
    lap_time = [0.0] * laps
    lap_cpu = [0.0] * laps  # process CPU time (local mapping runs inline): robust to a loaded machine
    lap_frames = [0] * laps
    rss: dict[int, float] = {}
    n_kf_prev = 0
    for frame in seq:
        lap = min(int(frame.index // per_lap), laps - 1)
        t0, c0 = time.perf_counter(), time.process_time()
        system.track(frame)
        lap_time[lap] += time.perf_counter() - t0
        lap_cpu[lap] += time.process_time() - c0
        lap_frames[lap] += 1
        n_kf = len(system.map.keyframes)
        lap_kfs[lap] += n_kf - n_kf_prev
        n_kf_prev = n_kf
        if frame.index + 1 in rss_at:
            rss[frame.index + 1] = _rss_mb()
    rss[n_frames] = _rss_mb()
    system.finish()
    ate = evaluate_trajectories(system.trajectory(), seq.ground_truth(), align="se3").ate.rmse
    stats = system.stats()
    n_bad = sum(1 for k in system.map.keyframes.values() if k.bad)
    return {
        "frames": n_frames, "laps": laps, "seed": seed, "ate_rmse": round(float(ate), 5),
        "keyframes_per_lap": lap_kfs, "keyframes": len(system.map.keyframes), "keyframes_culled": n_bad,
        "map_points_alive": int(np.count_nonzero(system.map.points.alive[: len(system.map.points)])),
        "fps_per_lap": [round(f / t, 1) for f, t in zip(lap_frames, lap_time)],
        "cpu_fps_per_lap": [round(f / t, 1) for f, t in zip(lap_frames, lap_cpu)],
        "rss_mb": {str(k): v for k, v in sorted(rss.items())},
        "frames_lost": stats["frames_lost"], "map_segments": stats["map_segments"], "loops": len(stats["loops"]),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=3000)
    ap.add_argument("--laps", type=int, default=10)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--height", type=int, default=480)
    ap.add_argument("--set", action="append", default=[], help="config override KEY=VALUE")
    a = ap.parse_args()
    print(json.dumps(run_lifelong(a.frames, a.laps, a.seed, a.width, a.height, tuple(a.set)), indent=1))


if __name__ == "__main__":
    main()
