"""The inertial figure of a run report: the IMU velocity and the biases per frame, from the run's
``imu_states.csv`` (:mod:`vslam.inertial.states_csv`); frames posed by the IMU alone are shaded."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from vslam.errors import VslamError
from vslam.report.page import new_figure, png_data_uri


def load_imu_states(folder: Path, notes: list[str]) -> dict[str, np.ndarray] | None:
    """The run folder's ``imu_states.csv``, or None (absent; unreadable: a note)."""
    from vslam.inertial.states_csv import read_imu_states

    path = Path(folder) / "imu_states.csv"
    if not path.is_file():
        return None
    try:
        states = read_imu_states(path)
    except VslamError as exc:
        notes.append(f"imu_states.csv not readable: {exc}")
        return None
    return states if len(states["timestamp"]) else None


def _shade_imu_only(ax, t: np.ndarray, imu_only: np.ndarray) -> None:
    """Grey spans over the runs of IMU-only frames."""
    idx = np.flatnonzero(imu_only > 0)
    if not len(idx):
        return
    runs = np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1)
    for k, r in enumerate(runs):
        ax.axvspan(t[r[0]], t[r[-1]], color="#bbbbbb", alpha=0.5, lw=0, label="IMU only" if k == 0 else None)


def plot_imu_states(states: dict[str, np.ndarray] | None) -> str | None:
    """Velocity (x, y, z and speed), gyro bias and accelerometer bias against time (PNG URI)."""
    if states is None:
        return None
    t = states["timestamp"] - states["timestamp"][0]
    fig = new_figure(6.4, 6.6)
    panels = (("v", "velocity [m/s]"), ("bg", "gyro bias [rad/s]"), ("ba", "accelerometer bias [m/s^2]"))
    for i, (key, label) in enumerate(panels):
        ax = fig.add_subplot(3, 1, i + 1)
        for axis, color in zip("xyz", ("#d62728", "#2ca02c", "#1f77b4")):
            ax.plot(t, states[f"{key}{axis}"], "-", color=color, lw=1.2, label=axis)
        if key == "v":
            speed = np.linalg.norm(np.column_stack([states["vx"], states["vy"], states["vz"]]), axis=1)
            ax.plot(t, speed, "--", color="#444444", lw=1.0, label="speed")
            ax.set_title("IMU state per frame (gravity-aligned world)")
        _shade_imu_only(ax, t, states["imu_only"])
        ax.set_ylabel(label, fontsize=8)
        ax.grid(alpha=0.3)
        ax.legend(loc="best", fontsize=7, ncol=5)
    ax.set_xlabel("time since the IMU initialization [s]")
    fig.tight_layout()
    return png_data_uri(fig)
