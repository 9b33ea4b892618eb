"""Drift and loop closure, demonstrated: noisy odometry around a circle, one loop edge, a pose graph.

Odometry composes noisy relative poses ``T_k_k+1 = T_true_k_k+1 Exp(w_k)``, ``w_k ~ N(0, diag(
sigma_rot^2, sigma_trans^2))``, so the error of ``T_world_k = T_0_1 ... T_k-1_k`` grows without
bound (a random walk on SE(3); Scaramuzza & Fraundorfer, "Visual Odometry Part I", 2011, Sec. VII).
A single loop-closure edge between the last and the first pose, optimized with
:func:`vslam.map.pose_graph.optimize_pose_graph`, spreads the accumulated error over the loop.
``scale_drift`` (monocular) additionally multiplies each step's translation by ``(1 + scale_drift)``
so the local scale grows along the loop; the Sim(3) graph (``sim3=True``) corrects it.
"""
from __future__ import annotations

import io
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vslam.map.pose_graph import optimize_pose_graph
from vslam.errors import ConfigError
from vslam.geometry.lie import inv_se3, make_sim3, so3_exp
from vslam.geometry.umeyama import umeyama
from vslam.outputs import atomic_write_bytes

LOG = logging.getLogger(__name__)


@dataclass
class LoopSimulation:
    """Truth ``T_true (N, 4, 4)``, dead-reckoned ``T_odom (N, 4, 4)``, the measured relative poses
    ``T_rel (N-1, 4, 4)`` (``T_odom_k^-1 T_odom_k+1``), the accumulated scale ``scale (N,)`` of each
    node's local map, and the sigmas of the odometry noise."""

    T_true: np.ndarray
    T_odom: np.ndarray
    T_rel: np.ndarray
    scale: np.ndarray
    sigma_rot: float
    sigma_trans: float


def simulate_loop(n_poses: int = 100, radius: float = 10.0, noise: float = 1.0, scale_drift: float = 0.0,
                  seed: int = 0) -> LoopSimulation:
    """A camera driving once around a circle (x-z plane, looking along the path, height wobbling).

    Each step's rotation is off by a systematic yaw bias of ``0.2 deg * noise`` (an uncalibrated
    odometry's heading drift) plus white noise of std ``0.1 deg * noise`` per axis, its translation by
    white noise of ``0.005 m * noise`` per axis; the last pose is one step before the first, so an edge ``(N-1, 0)``
    closes the loop.
    """
    if n_poses < 3:
        raise ConfigError(f"drift demo needs at least 3 poses, got {n_poses}")
    if noise < 0:
        raise ConfigError(f"drift demo noise level must be >= 0, got {noise}")
    rng = np.random.default_rng(seed)
    ang = 2 * np.pi * np.arange(n_poses) / n_poses
    T_true = np.tile(np.eye(4), (n_poses, 1, 1))
    T_true[:, :3, 3] = np.stack([radius * np.sin(ang), 0.3 * np.sin(3 * ang), radius * np.cos(ang) - radius], axis=1)
    # yaw about the world y axis so the optical axis (camera z) points along the direction of motion
    T_true[:, :3, :3] = so3_exp(np.stack([0 * ang, np.pi / 2 - ang, 0 * ang], axis=1))
    sigma_rot = np.deg2rad(0.1) * noise
    sigma_trans = 0.005 * noise
    yaw_bias = np.deg2rad(0.2) * noise
    T_true_rel = inv_se3(T_true[:-1]) @ T_true[1:]
    m = n_poses - 1
    noise_T = np.tile(np.eye(4), (m, 1, 1))
    noise_T[:, :3, :3] = so3_exp(rng.normal(0.0, 1.0, (m, 3)) * sigma_rot + np.array([0.0, yaw_bias, 0.0]))
    noise_T[:, :3, 3] = rng.normal(0.0, 1.0, (m, 3)) * sigma_trans
    T_rel = T_true_rel @ noise_T
    scale = (1.0 + scale_drift) ** np.arange(n_poses)
    T_rel[:, :3, 3] *= scale[1:, None]
    T_odom = np.empty_like(T_true)
    T_odom[0] = T_true[0]
    for k in range(m):  # sequential composition along the path (N small)
        T_odom[k + 1] = T_odom[k] @ T_rel[k]
    return LoopSimulation(T_true, T_odom, T_rel, scale, float(sigma_rot), float(sigma_trans))


def ate_rmse(T_est: np.ndarray, T_true: np.ndarray, with_scale: bool = False) -> float:
    """Position RMSE after Umeyama alignment (Sim(3) when ``with_scale``), Sturm et al. 2012."""
    p_est, p_true = T_est[:, :3, 3], T_true[:, :3, 3]
    R, t, s = umeyama(p_est, p_true, with_scale)
    err = (s * p_est @ R.T + t) - p_true
    return float(np.sqrt(np.mean(np.sum(err**2, axis=1))))


def close_loop(sim: LoopSimulation, sim3: bool = False) -> np.ndarray:
    """Odometry edges plus one loop edge ``(N-1, 0)`` (true relative pose, 10x more precise), optimized.

    Returns the corrected ``T_world_cam (N, 4, 4)`` (Sim(3): the rigid part; the per-node scales are
    applied to positions relative to the fixed first node, i.e. ``S_world_cam`` translations).
    """
    n = len(sim.T_true)
    info = np.diag([1 / sim.sigma_rot**2] * 3 + [1 / sim.sigma_trans**2] * 3 + ([1e4] if sim3 else []))
    edges = [(k, k + 1, sim.T_rel[k], info) for k in range(n - 1)]
    T_loop = inv_se3(sim.T_true[-1]) @ sim.T_true[0]
    if sim3:
        # the loop measures node 0 in the frame of node N-1, whose local map is scale[-1] larger
        S_loop = make_sim3(sim.scale[-1], T_loop[:3, :3], sim.scale[-1] * T_loop[:3, 3])
        edges.append((n - 1, 0, S_loop, 100.0 * info))
    else:
        edges.append((n - 1, 0, T_loop, 100.0 * info))
    res = optimize_pose_graph(sim.T_odom, edges, fixed=[0], sim3=sim3)
    return res.S_world_cam if sim3 else res.T_world_cam


def run_drift_demo(output_dir: str | Path, noise: float = 1.0, seed: int = 0, n_poses: int = 100) -> dict:
    """Simulate, close the loop, plot ``drift_demo.png`` (top view) and return the numbers.

    Returns:
        dict with ``end_drift_before`` / ``end_drift_after`` (m, last position error),
        ``ate_before`` / ``ate_after`` (m, RMSE after SE(3) alignment), ``path_length`` (m) and ``plot``.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    output_dir = Path(output_dir)
    try:
        output_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(f"cannot create output folder {output_dir}: {exc}") from exc
    sim = simulate_loop(n_poses=n_poses, noise=noise, seed=seed)
    T_fix = close_loop(sim)
    p_true, p_odom, p_fix = sim.T_true[:, :3, 3], sim.T_odom[:, :3, 3], T_fix[:, :3, 3]
    out = {
        "end_drift_before": float(np.linalg.norm(p_odom[-1] - p_true[-1])),
        "end_drift_after": float(np.linalg.norm(p_fix[-1] - p_true[-1])),
        "ate_before": ate_rmse(sim.T_odom, sim.T_true),
        "ate_after": ate_rmse(T_fix, sim.T_true),
        "path_length": float(np.sum(np.linalg.norm(np.diff(p_true, axis=0), axis=1))),
        "noise": float(noise),
        "seed": int(seed),
    }
    fig = Figure(figsize=(6.5, 6))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    ax.plot(p_true[:, 0], p_true[:, 2], "k-", lw=2, label="ground truth")
    ax.plot(p_odom[:, 0], p_odom[:, 2], "r--", label=f"odometry (ATE {out['ate_before']:.2f} m)")
    ax.plot(p_fix[:, 0], p_fix[:, 2], "g-", label=f"after loop closure (ATE {out['ate_after']:.2f} m)")
    ax.plot([p_odom[-1, 0], p_odom[0, 0]], [p_odom[-1, 2], p_odom[0, 2]], "b:", label="loop edge")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("z [m]")
    ax.set_aspect("equal")
    ax.set_title(f"Drift and loop closure (noise x{noise:g}, {n_poses} poses)")
    ax.legend(loc="best", fontsize=8)
    path = output_dir / "drift_demo.png"
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    atomic_write_bytes(path, buf.getvalue())
    out["plot"] = str(path)
    LOG.info("drift demo: end drift %.3f -> %.3f m, ATE %.3f -> %.3f m", out["end_drift_before"],
             out["end_drift_after"], out["ate_before"], out["ate_after"])
    return out
