"""Pose-error helpers shared by the backend tests."""
from __future__ import annotations

import numpy as np


def pose_errors(T_est: np.ndarray, T_true: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-pose translation error (m) and rotation error (deg)."""
    dt = np.linalg.norm(T_est[:, :3, 3] - T_true[:, :3, 3], axis=1)
    dR = np.transpose(T_est[:, :3, :3], (0, 2, 1)) @ T_true[:, :3, :3]
    cos = np.clip((np.trace(dR, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    return dt, np.degrees(np.arccos(cos))


def rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x))))
