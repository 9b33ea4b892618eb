"""Backend timings: one local BA (10 keyframes, 3000 points, ~15k observations), pose graphs, EKF.

Run: ``python benchmarks/backend_bench.py [--repeats N] [--no-gtsam] [--output FILE.json]``.
Wall-clock times on a shared machine include waiting for the CPU, so the process CPU time is
reported next to it (BLAS is held to one thread inside the solver) together with the load average.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import time

import numpy as np

from vslam.backend.bundle_adjustment import local_bundle_adjustment
from vslam.backend.config import LocalBAConfig
from vslam.backend.drift_demo import simulate_loop
from vslam.backend.ekf import PoseEKF
from vslam.geometry.lie import make_sim3
from vslam.map.pose_graph import optimize_pose_graph
from vslam.backend.synthetic import make_ba_problem


def _timed(fn, repeats: int) -> tuple[dict, object]:
    walls, cpus, out = [], [], None
    for _ in range(repeats):
        c0, t0 = time.process_time(), time.perf_counter()
        out = fn()
        walls.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
    return {
        "wall_median_ms": 1e3 * float(np.median(walls)), "wall_min_ms": 1e3 * float(np.min(walls)),
        "cpu_median_ms": 1e3 * float(np.median(cpus)), "cpu_min_ms": 1e3 * float(np.min(cpus)), "repeats": repeats,
    }, out


def _local_ba(sensor: str, solver: str, repeats: int) -> dict:
    problem, truth = make_ba_problem(n_keyframes=10, n_points=3000, obs_per_point=6, sensor=sensor, seed=0)
    stats, res = _timed(lambda: local_bundle_adjustment(problem, LocalBAConfig(solver=solver)), repeats)
    free = ~np.isin(problem.kf_ids, problem.fixed_kf_ids)
    err = np.linalg.norm(res.T_world_cam[free, :3, 3] - truth.T_world_cam[free, :3, 3], axis=1)
    stats.update(
        sensor=sensor, solver=solver, keyframes=problem.num_keyframes, points=problem.num_points,
        observations=problem.num_observations, iterations=res.iterations,
        build_ms=1e3 * res.build_time_s, translation_rmse_mm=1e3 * float(np.sqrt(np.mean(err**2))),
        outlier_recall=float(np.mean(~res.inlier_mask[truth.outlier])),
    )
    return stats


def _pose_graph(n: int, sim3: bool, repeats: int) -> dict:
    sim = simulate_loop(n_poses=n, scale_drift=0.002 if sim3 else 0.0, seed=0)
    edges = [(k, k + 1, sim.T_rel[k]) for k in range(n - 1)]
    T_loop = np.linalg.inv(sim.T_true[-1]) @ sim.T_true[0]
    edges.append((n - 1, 0, make_sim3(sim.scale[-1], T_loop[:3, :3], sim.scale[-1] * T_loop[:3, 3]) if sim3 else T_loop))
    stats, res = _timed(lambda: optimize_pose_graph(sim.T_odom, edges, sim3=sim3), repeats)
    stats.update(nodes=n, edges=len(edges), sim3=sim3, iterations=res.iterations)
    return stats


def _ekf(steps: int = 1000) -> dict:
    ekf = PoseEKF(T_world_cam=np.eye(4))
    T = np.eye(4)
    c0, t0 = time.process_time(), time.perf_counter()
    for k in range(steps):
        ekf.predict(1 / 30)
        T[0, 3] = 0.01 * k
        ekf.update(T, (0.01, 0.01))
    return {"us_per_step_wall": 1e6 * (time.perf_counter() - t0) / steps,
            "us_per_step_cpu": 1e6 * (time.process_time() - c0) / steps, "steps": steps}


def run_backend_bench(repeats: int = 5, include_gtsam: bool = True) -> dict:
    """Time the backend; returns a JSON-able dict (see the module docstring)."""
    out: dict = {
        "machine": {"platform": platform.platform(), "cpus": os.cpu_count(), "loadavg_start": os.getloadavg()},
        "local_ba": [_local_ba("stereo", "schur", repeats), _local_ba("mono", "schur", repeats),
                     _local_ba("rgbd", "schur", repeats)],
    }
    if include_gtsam:
        out["local_ba"].append(_local_ba("stereo", "gtsam", 1))
    out["pose_graph"] = [_pose_graph(200, False, repeats), _pose_graph(200, True, repeats)]
    out["ekf"] = _ekf()
    out["machine"]["loadavg_end"] = os.getloadavg()
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--no-gtsam", action="store_true", help="skip the (slow) GTSAM reference BA")
    parser.add_argument("--output", help="also write the JSON here")
    args = parser.parse_args()
    result = run_backend_bench(args.repeats, not args.no_gtsam)
    text = json.dumps(result, indent=2)
    print(text)  # noqa: T201 - command-line output
    if args.output:
        with open(args.output, "w") as fh:
            fh.write(text + "\n")


if __name__ == "__main__":
    main()
