"""A stand-in runner that writes a synthetic run folder without running SLAM.

It has the signature of :func:`vslam.api.run_path`, so the benchmark harness, the report and the
Ray path can be exercised (``vslam bench SPEC --dry-run``, the tests) in a fraction of a second.
The run folder follows the ``vslam run`` contract: ``trajectory.txt`` (a 2 m circle, every frame
displaced by exactly ``ate`` metres along z with alternating sign, so its ATE RMSE before alignment
is ``ate``), ``groundtruth.txt`` (the circle), ``keyframes.txt``, ``sparse.ply`` (a coloured ring
of points), ``stats.json`` (one loop closure, last frame -> first) and ``config.yaml``.

Behaviour is set through ``overrides`` (``fake.KEY=VALUE``): ``fake.ate`` (default 0.01 m),
``fake.fps`` (100; written as the run's ``fps``), ``fake.frames`` (20, or ``max_frames``),
``fake.rate`` (10 Hz, the sensor's frame rate), ``fake.fail=true`` (raise a RuntimeError after
writing a partial stats.json), ``fake.crash=true`` (kill the process), ``fake.sleep`` (seconds).
Other overrides are ignored.
"""
from __future__ import annotations

import json
import os
import time
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from vslam.trajectory import Trajectory, write_tum


def _options(overrides) -> dict[str, Any]:
    opts: dict[str, Any] = {"ate": 0.01, "fps": 100.0, "frames": 20, "rate": 10.0, "fail": False,
                            "crash": False, "sleep": 0.0}
    for text in overrides or ():
        key, _, raw = str(text).partition("=")
        if key.startswith("fake."):
            opts[key[5:]] = yaml.safe_load(raw)
    return opts


def circle_trajectory(n: int, rate: float, radius: float = 2.0, start_frame: int = 0) -> Trajectory:
    """``T_world_cam`` on a horizontal circle (x-y plane), the camera looking at its centre."""
    idx = np.arange(start_frame, start_frame + n)
    ang = 2 * np.pi * (idx - start_frame) / max(n, 1)
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, 0, 3] = radius * np.cos(ang)
    T[:, 1, 3] = radius * np.sin(ang)
    c, s = np.cos(ang + np.pi), np.sin(ang + np.pi)
    # camera z (forward) towards the centre, camera y down (-world z)
    T[:, :3, 2] = np.stack([c, s, np.zeros(n)], 1)
    T[:, :3, 1] = np.array([0.0, 0.0, -1.0])
    T[:, :3, 0] = np.cross(T[:, :3, 1], T[:, :3, 2])
    return Trajectory(idx / rate, T)


def write_ply(path: Path, xyz: np.ndarray, rgb: np.ndarray | None = None) -> None:
    """ASCII PLY with ``x y z [red green blue]``."""
    lines = ["ply", "format ascii 1.0", f"element vertex {len(xyz)}",
             "property float x", "property float y", "property float z"]
    if rgb is not None:
        lines += ["property uchar red", "property uchar green", "property uchar blue"]
    lines.append("end_header")
    if rgb is None:
        body = [f"{p[0]:.5f} {p[1]:.5f} {p[2]:.5f}" for p in xyz]
    else:
        body = [f"{p[0]:.5f} {p[1]:.5f} {p[2]:.5f} {int(c[0])} {int(c[1])} {int(c[2])}" for p, c in zip(xyz, rgb)]
    path.write_text("\n".join(lines + body) + "\n")


def fake_run(path: str | Path, output: str | Path | None, sensor: str | None = None, dataset: str | None = None,
             config: Any = None, overrides=(), max_frames: int | None = None, start_frame: int = 0,
             progress: bool = False) -> dict:
    """Write a synthetic run folder to ``output`` and return its stats (see the module docstring)."""
    o = _options(overrides)
    if o["sleep"]:
        time.sleep(float(o["sleep"]))
    if o["crash"]:
        os._exit(3)
    n = int(max_frames or o["frames"])
    rate = float(o["rate"])
    ate = float(o["ate"])
    gt = circle_trajectory(n, rate, start_frame=start_frame)
    T_est = gt.T_world_cam.copy()
    T_est[:, 2, 3] += ate * np.where(np.arange(n) % 2 == 0, 1.0, -1.0)
    est = Trajectory(gt.timestamps.copy(), T_est)
    stats = {
        "frames": n, "tracked": n, "lost": 0, "keyframes": max(1, n // 5), "map_points": 200,
        "loops": [[start_frame + n - 1, start_frame, 57]], "wall_s": round(n / float(o["fps"]), 3),
        "fps": float(o["fps"]), "stage_ms": {"features": 4.0, "tracking": 3.0, "mapping": 2.5, "total": 9.5},
        "sensor": sensor or "mono", "dataset": "fake", "path": str(path), "start_frame": start_frame,
        "frame_rate": rate, "ate_rmse": ate, "rpe_trans_rmse": 2 * ate, "rpe_rot_deg_rmse": 0.0,
        "matched_poses": n, "scale": 1.0, "pid": os.getpid(),
    }
    if output is None:
        return stats
    out = Path(output)
    out.mkdir(parents=True, exist_ok=True)
    (out / "config.yaml").write_text(yaml.safe_dump({"fake": {k: v for k, v in o.items()}}))
    if o["fail"]:
        (out / "stats.json").write_text(json.dumps({**stats, "error": "RuntimeError: fake failure"}))
        raise RuntimeError("fake failure (fake.fail=true)")
    write_tum(out / "trajectory.txt", est)
    write_tum(out / "groundtruth.txt", gt)
    write_tum(out / "keyframes.txt", est.subset(np.arange(0, n, 5)))
    ang = np.linspace(0, 2 * np.pi, 200, endpoint=False)
    xyz = np.stack([3.0 * np.cos(ang), 3.0 * np.sin(ang), 0.5 * np.sin(3 * ang)], 1)
    rgb = np.stack([127 + 127 * np.cos(ang), 127 + 127 * np.sin(ang), np.full(200, 90.0)], 1).astype(int)
    write_ply(out / "sparse.ply", xyz, rgb)
    (out / "stats.json").write_text(json.dumps(stats, indent=2))
    return stats
