"""Seeded synthetic bundle-adjustment problems with exact ground truth (tests and benchmarks)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vslam.backend.problem import BAProblem
from vslam.geometry.camera import PinholeCamera
from vslam.geometry.lie import so3_exp


@dataclass
class SyntheticTruth:
    """Exact poses/points of a synthetic problem and which observations were made outliers."""

    T_world_cam: np.ndarray
    X_world: np.ndarray
    outlier: np.ndarray


def make_ba_problem(
    n_keyframes: int = 10, n_points: int = 3000, obs_per_point: int = 5, sensor: str = "stereo",
    noise_px: float = 1.0, outlier_fraction: float = 0.05, pose_noise_m: float = 0.02,
    pose_noise_deg: float = 0.5, point_noise_m: float = 0.05, n_fixed: int | None = None,
    max_octave: int = 0, scale_factor: float = 1.2, baseline: float = 0.5, seed: int = 0,
) -> tuple[BAProblem, SyntheticTruth]:
    """Keyframes 0.2 m apart along x (slowly yawing), points 4-12 m in front, noisy observations.

    Each point is seen by a run of about ``obs_per_point`` consecutive keyframes (those that see it in
    the image). ``sensor`` is ``"mono"``, ``"stereo"`` (``baseline`` m, KITTI-like 0.5 by default) or
    ``"rgbd"``. A fraction ``outlier_fraction`` of observations is displaced by 15-60 px. The first
    ``n_fixed`` keyframes (default 2 mono, 1 otherwise) are exact and fixed; the others are
    perturbed by ``pose_noise_m`` / ``pose_noise_deg`` per axis, points by ``point_noise_m``.
    Pixel noise has std ``noise_px * scale_factor ** octave``, the octave uniform in ``0..max_octave``
    (the declared ``obs_sigma`` is ``scale_factor ** octave``); RGB-D depth noise is ``1 % * noise_px``.
    """
    rng = np.random.default_rng(seed)
    cam = PinholeCamera(500.0, 500.0, 320.0, 240.0, 640, 480, baseline=baseline if sensor == "stereo" else None)
    n_fixed = (2 if sensor == "mono" else 1) if n_fixed is None else n_fixed
    T_true = np.tile(np.eye(4), (n_keyframes, 1, 1))
    idx = np.arange(n_keyframes)
    T_true[:, :3, :3] = so3_exp(np.stack([0.01 * np.sin(idx), np.deg2rad(1.0) * idx, 0.0 * idx], axis=1))
    T_true[:, :3, 3] = np.stack([0.2 * idx, 0.03 * np.sin(0.7 * idx), 0.05 * idx], axis=1)
    # points: back-project random pixels/depths of a random keyframe
    ref = rng.integers(0, n_keyframes, n_points)
    uv = rng.uniform([20, 20], [620, 460], (n_points, 2))
    X_ref = cam.backproject(uv, rng.uniform(4.0, 12.0, n_points))
    X_true = np.einsum("pij,pj->pi", T_true[ref, :3, :3], X_ref) + T_true[ref, :3, 3]
    # visibility of every point in every keyframe
    R_cw = np.transpose(T_true[:, :3, :3], (0, 2, 1))
    X_cam = np.einsum("kij,pj->kpi", R_cw, X_true) - np.einsum("kij,kj->ki", R_cw, T_true[:, :3, 3])[:, None, :]
    z = X_cam[..., 2]
    uv_all = np.stack([cam.fx * X_cam[..., 0] / z + cam.cx, cam.fy * X_cam[..., 1] / z + cam.cy], axis=-1)
    vis = (z > 0.1) & (uv_all[..., 0] > 0) & (uv_all[..., 0] < cam.width - 1)
    vis &= (uv_all[..., 1] > 0) & (uv_all[..., 1] < cam.height - 1)
    start = np.clip(ref - rng.integers(0, obs_per_point, n_points), 0, None)
    run = (idx[:, None] >= start[None, :]) & (idx[:, None] < start[None, :] + obs_per_point)
    seen = vis & run
    seen[ref, np.arange(n_points)] = True
    kf_i, pt_i = np.nonzero(seen)
    m = len(kf_i)
    octave = rng.integers(0, max_octave + 1, m)
    sigma = scale_factor**octave  # the std the problem declares (noise_px = 0 gives exact data)
    obs_uv = uv_all[kf_i, pt_i] + rng.normal(0.0, 1.0, (m, 2)) * (noise_px * sigma)[:, None]
    zc = z[kf_i, pt_i]
    outlier = rng.random(m) < outlier_fraction
    ang = rng.uniform(0, 2 * np.pi, outlier.sum())
    mag = rng.uniform(15.0, 60.0, outlier.sum())
    obs_uv[outlier] += np.stack([np.cos(ang), np.sin(ang)], axis=1) * mag[:, None]
    u_right = depth = None
    if sensor == "stereo":
        u_right = uv_all[kf_i, pt_i, 0] - cam.fx * cam.baseline / zc + rng.normal(0.0, 1.0, m) * noise_px * sigma
        u_right[outlier] += rng.uniform(-30, 30, outlier.sum())
    elif sensor == "rgbd":
        depth = zc * (1.0 + 0.01 * noise_px * rng.normal(0.0, 1.0, m))
        depth[outlier] *= rng.uniform(0.5, 1.5, outlier.sum())
    elif sensor != "mono":
        raise ValueError(f"sensor must be mono, stereo or rgbd, got {sensor!r}")
    T_init = T_true.copy()
    free = idx >= n_fixed
    nf = int(free.sum())
    T_init[free, :3, :3] = so3_exp(rng.normal(0.0, np.deg2rad(pose_noise_deg), (nf, 3))) @ T_true[free, :3, :3]
    T_init[free, :3, 3] += rng.normal(0.0, pose_noise_m, (nf, 3))
    X_init = X_true + rng.normal(0.0, point_noise_m, X_true.shape)
    kf_ids = 100 + idx  # ids differ from rows on purpose
    pt_ids = 1000 + np.arange(n_points)
    problem = BAProblem(
        camera=cam, kf_ids=kf_ids, T_world_cam=T_init, pt_ids=pt_ids, X_world=X_init,
        obs_kf=kf_ids[kf_i], obs_pt=pt_ids[pt_i], obs_uv=obs_uv, obs_sigma=sigma,
        obs_u_right=u_right, obs_depth=depth, fixed_kf_ids=kf_ids[:n_fixed],
    )
    return problem, SyntheticTruth(T_true, X_true, outlier)
