"""Time per call of the geometry core on synthetic scenes (1 px noise, 30 % outliers).

Run ``python benchmarks/geometry_bench.py`` (prints a table) or call :func:`run_geometry_bench`
(returns ``{name: {"ms_median": .., "ms_min": .., "n_points": ..}}``) from ``vslam bench``.
Timings are wall-clock medians over ``repeats`` calls in this process (OpenCV threads as set).
"""
from __future__ import annotations

import time
from typing import Callable

import numpy as np

from vslam.geometry import (
    align_points,
    essential_8point,
    estimate_essential,
    inv_T,
    make_T,
    normalize_points,
    recover_pose,
    relative_scale,
    so3_exp,
    solve_pnp,
    transform_points,
    triangulate,
)

K = np.array([[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]])


def _scene(n: int, seed: int = 0, noise_px: float = 1.0, outlier_frac: float = 0.3):
    """``n`` points at 4-12 m seen by two cameras 0.6-1.2 m apart; returns poses, points, pixels."""
    rng = np.random.default_rng(seed)
    uv = rng.uniform([0, 0], [640, 480], (n, 2))
    z = rng.uniform(4, 12, n)
    X_world = np.c_[(uv - K[:2, 2]) / K[0, 0] * z[:, None], z]  # world = camera 1
    d = np.array([1.0, 0.1, 0.2]) / np.linalg.norm([1.0, 0.1, 0.2])
    T_cam2_world = make_T(so3_exp(np.radians([1.0, -3.0, 2.0])), 0.9 * d)
    Xc2 = transform_points(T_cam2_world, X_world)
    x1 = uv + rng.normal(scale=noise_px, size=(n, 2))
    x2 = Xc2[:, :2] / Xc2[:, 2:] * K[0, 0] + K[:2, 2] + rng.normal(scale=noise_px, size=(n, 2))
    k = int(outlier_frac * n)
    x2[:k] = rng.uniform([0, 0], [640, 480], (k, 2))
    return np.eye(4), T_cam2_world, X_world, x1, x2


def _time(fn: Callable[[], object], repeats: int) -> tuple[float, float, float]:
    """Median and best wall time and median CPU time of this process (ms); CPU time is what to
    compare on a shared, loaded machine (it excludes waiting for a core)."""
    fn()  # warm-up (imports, OpenCV initialisation)
    ts, cs = [], []
    for _ in range(repeats):
        c0 = time.process_time()
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
        cs.append(time.process_time() - c0)
    return 1e3 * float(np.median(ts)), 1e3 * float(np.min(ts)), 1e3 * float(np.median(cs))


def run_geometry_bench(repeats: int = 20, threads: int | None = 1) -> dict[str, dict[str, float]]:
    """Median and best time per call (ms) of the main geometry functions.

    ``threads``: OpenCV threads during the run (1 by default, so CPU time = single-core cost;
    ``None`` leaves OpenCV's setting alone). The previous setting is restored afterwards.
    """
    import cv2

    old_threads = cv2.getNumThreads()
    if threads is not None:
        cv2.setNumThreads(threads)
    try:
        return _run(repeats)
    finally:
        cv2.setNumThreads(old_threads)


def _run(repeats: int) -> dict[str, dict[str, float]]:
    out: dict[str, dict[str, float]] = {}

    def add(name: str, n: int, fn: Callable[[], object]) -> None:
        med, best, cpu = _time(fn, repeats)
        out[name] = {"ms_median": med, "ms_min": best, "cpu_ms_median": cpu, "n_points": n}

    T1, T2, X, x1, x2 = _scene(1000, seed=1)
    add("estimate_essential (USAC 5-pt, conf 1-1e-9, + LM)", 1000, lambda: estimate_essential(x1, x2, K))
    add("estimate_essential, conf 0.999 (+ LM)", 1000, lambda: estimate_essential(x1, x2, K, confidence=0.999))
    add("estimate_essential, conf 0.999, no LM", 1000,
        lambda: estimate_essential(x1, x2, K, confidence=0.999, refine=False))
    E, mask = estimate_essential(x1, x2, K)
    add("recover_pose (cheirality + pure-rotation test)", 1000, lambda: recover_pose(E, x1, x2, K, mask))
    n1, n2 = normalize_points(x1[300:], K), normalize_points(x2[300:], K)
    add("essential_8point (inliers only)", 700, lambda: essential_8point(n1, n2))
    add("triangulate (linear DLT, OpenCV)", 1000, lambda: triangulate(T1, T2, K, x1, x2))

    _, T2p, Xp, _, x2p = _scene(500, seed=2)
    add("solve_pnp (P3P RANSAC + LM), 30% outl.", 500, lambda: solve_pnp(Xp, x2p, K))
    add("solve_pnp with motion-model guess", 500, lambda: solve_pnp(Xp, x2p, K, T_cam_world_init=T2p))

    rng = np.random.default_rng(3)
    src = X[:500]
    dst = 1.3 * transform_points(inv_T(T2), src) + rng.normal(scale=0.03, size=src.shape)
    dst[:150] = rng.uniform(-10, 10, (150, 3))
    add("align_points Sim(3) RANSAC, thr=0.1", 500, lambda: align_points(src, dst, True, threshold=0.1))
    add("align_points Sim(3) LMedS (no thr)", 500, lambda: align_points(src, dst, True))
    add("relative_scale", 500, lambda: relative_scale(src, dst / 1.3))
    return out


def format_table(results: dict[str, dict[str, float]]) -> str:
    lines = [f"{'function':52s} {'N':>5s} {'median ms':>10s} {'min ms':>8s} {'CPU ms':>8s}"]
    for name, r in results.items():
        lines.append(f"{name:52s} {int(r['n_points']):5d} {r['ms_median']:10.2f} {r['ms_min']:8.2f}"
                     f" {r['cpu_ms_median']:8.2f}")
    return "\n".join(lines)


if __name__ == "__main__":
    print(format_table(run_geometry_bench()))
