"""Shared synthetic data and ATE helper for the frontend tests (not a test module)."""
from __future__ import annotations

import functools

import numpy as np

from vslam.datasets.synthetic.sequence import SyntheticConfig, SyntheticSequence
from vslam.trajectory import Trajectory
from vslam.geometry.umeyama import umeyama

N_FRAMES = 40


@functools.lru_cache(maxsize=1)
def synthetic_frames():
    """40 frames (320x240, 1 grey-level pixel noise) of a 0.15-lap loop: ~3 cm and ~1 deg per frame."""
    cfg = SyntheticConfig(n_frames=N_FRAMES, laps=0.15, width=320, height=240, fx=262.5, fy=262.5,
                          cx=159.5, cy=119.5, pixel_noise=1.0, seed=3)
    seq = SyntheticSequence(cfg)
    return seq.camera, list(seq), seq.ground_truth()


def ate_rmse(est: Trajectory, gt: Trajectory, with_scale: bool) -> float:
    """RMSE of positions after Umeyama SE(3)/Sim(3) alignment, frames matched by timestamp."""
    idx = np.searchsorted(gt.timestamps, est.timestamps)
    idx = np.clip(idx, 0, len(gt) - 1)
    ok = np.abs(gt.timestamps[idx] - est.timestamps) < 1e-3
    P, Q = est.positions[ok], gt.positions[idx[ok]]
    R, t, s = umeyama(P, Q, with_scale=with_scale)
    e = Q - (s * P @ R.T + t)
    return float(np.sqrt((e ** 2).sum(axis=1).mean()))
