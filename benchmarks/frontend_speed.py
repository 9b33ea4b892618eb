"""Per-frame speed of the tracking hot path on the three target sequences (issue 4).

Runs the pipeline as :func:`vslam.api.run_path` does (image loading included) with
``backend.local_ba=false`` and ``loop.enabled=false`` on:

* ``7scenes_rgbd``: 7-Scenes redkitchen, first 300 frames, RGB-D 640x480 (target >= 30 frames/s);
* ``kitti06_stereo``: KITTI 06 frames 0-50, stereo 1226x370 (target >= 10 frames/s);
* ``kitti07_mono``: KITTI 07 frames 0-159, monocular 1226x370 (target >= 10 frames/s).

For each it reports wall frames/s, process CPU ms per frame over the frame loop
(``time.process_time``: the number to compare on a loaded, shared machine; wall time there can be
twice the CPU time), the mean per-stage ms from ``stats["stage_ms"]``, the ATE
RMSE and the 1-minute load average at the start (``os.getloadavg``).

Run ``python benchmarks/frontend_speed.py [SHARED_DATA] [NAMES...] [--prefetch N] [--max-frames N]
[--set key=value]`` (prints a table and the JSON) or call :func:`run_frontend_speed`.
"""
from __future__ import annotations

import json
import logging
import os
import sys
import time
from pathlib import Path

SEQUENCES: dict[str, dict] = {
    "7scenes_rgbd": {"path": "7scenes_redkitchen", "sensor": "rgbd", "max_frames": 300, "target_fps": 30.0},
    "kitti06_stereo": {"path": "kitti_odometry/sequences/06", "sensor": "stereo", "max_frames": None,
                       "target_fps": 10.0},
    "kitti07_mono": {"path": "kitti_odometry/sequences/07", "sensor": "mono", "max_frames": None,
                     "target_fps": 10.0},
}
OVERRIDES = ("backend.local_ba=false", "loop.enabled=false")


class _Clock:
    """Process CPU time (all threads: tracking and background decoding) from the start of the
    frame loop to the last tracked frame (dataset indexing, ground truth and imports excluded)."""

    def __init__(self) -> None:
        self.start = time.process_time()
        self.end = self.start

    def __call__(self, frame, result) -> None:  # run_sequence's on_frame callback
        self.end = time.process_time()


def run_frontend_speed(shared_data: Path, names: list[str] | None = None,
                       overrides: tuple[str, ...] = OVERRIDES, prefetch_depth: int = 4,
                       max_frames: int | None = None, prefetch_mode: str = "auto") -> dict:
    """``{name: {"fps", "cpu_ms_per_frame", "read_ms", "stage_ms", "ate_rmse", "frames", "tracked",
    "load1", "target_fps"}}`` for the sequences in :data:`SEQUENCES` (all unless ``names``).

    ``read_ms`` is the mean time the tracker waited for a decoded frame (with ``prefetch_depth``
    > 0 decoding runs in a background thread, :func:`vslam.datasets.prefetch.prefetch`);
    ``max_frames`` overrides the clip length of every sequence. ``prefetch_mode`` is
    :func:`vslam.runner.run_sequence`'s (``auto``: a child process reads and detects on long
    clips; then ``cpu_ms_per_frame`` is this process's CPU only, the child's is not in it)."""
    from vslam.config import Config, load_config
    from vslam.datasets import open_dataset
    from vslam.datasets.prefetch import FrameRange, choose_prefetch
    from vslam.runner import run_sequence
    from vslam.system import System

    shared_data = Path(shared_data)
    out: dict[str, dict] = {}
    for name, spec in SEQUENCES.items():
        if names and name not in names:
            continue
        path = shared_data / spec["path"]
        if not path.exists():
            logging.getLogger(__name__).warning("skipping %s: %s is missing", name, path)
            continue
        cfg = load_config(Config, None, list(overrides))
        ds = open_dataset(path, sensor=spec["sensor"])
        limit = max_frames if max_frames is not None else spec["max_frames"]
        stop = len(ds) if limit is None else min(len(ds), limit)
        system = System(cfg, ds.camera, sensor=spec["sensor"])
        gt = ds.ground_truth()
        load1 = os.getloadavg()[0]
        clock = _Clock()
        frames = FrameRange(ds, 0, stop)
        mode = "none" if prefetch_depth <= 0 else choose_prefetch(prefetch_mode, frames, stop)
        res = run_sequence(system, frames, total=stop, config=cfg, ground_truth=gt,
                           align="sim3" if spec["sensor"] == "mono" else "se3", progress=False,
                           on_frame=clock, prefetch_depth=prefetch_depth, prefetch_mode=mode)
        s = res.stats
        n = max(1, int(s["frames"]))
        out[name] = {
            "fps": s["fps"],
            "cpu_ms_per_frame": round(1000.0 * (clock.end - clock.start) / n, 1),
            "read_ms": s.get("read_ms"),
            "stage_ms": s.get("stage_ms", {}),
            "ate_rmse": s.get("ate_rmse"),
            "frames": s["frames"],
            "tracked": s["tracked"],
            "load1": round(load1, 2),
            "target_fps": spec["target_fps"],
            "prefetch": mode,
        }
    return out


def main(argv: list[str]) -> int:
    import argparse

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("shared", nargs="?", default=str(Path(__file__).resolve().parents[2] / "shared" / "data"))
    p.add_argument("names", nargs="*", help=f"sequences to run (default all): {', '.join(SEQUENCES)}")
    p.add_argument("--prefetch", type=int, default=4, help="frames decoded ahead (0: decode in the tracking thread)")
    p.add_argument("--mode", default="auto", help="prefetch mode: auto, thread, process, none")
    p.add_argument("--max-frames", type=int, default=None, help="clip length for every sequence")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="extra config override")
    a = p.parse_args(argv[1:])
    res = run_frontend_speed(Path(a.shared), a.names or None, OVERRIDES + tuple(a.set), a.prefetch, a.max_frames,
                             a.mode)
    for name, r in res.items():
        st = " ".join(f"{k}={v:.1f}" for k, v in r["stage_ms"].items() if isinstance(v, (int, float)))
        ate = f"{r['ate_rmse']:.4f}" if r["ate_rmse"] is not None else "-"
        print(f"{name:15s} {r['fps']:6.1f} fps (target {r['target_fps']:.0f})  cpu {r['cpu_ms_per_frame']:6.1f} "
              f"ms/frame  read {r['read_ms']} ms  {r['prefetch']}  ATE {ate}  load {r['load1']}  [{st}]")
    print(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
