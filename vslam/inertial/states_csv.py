"""``imu_states.csv`` of an inertial run: one row per frame posed after the IMU initialization.

Columns: ``timestamp`` (s, camera clock), ``vx, vy, vz`` (the IMU's velocity in the gravity-aligned
world, m/s, as estimated at that frame), ``bgx, bgy, bgz`` (gyro bias, rad/s), ``bax, bay, baz``
(accelerometer bias, m/s^2) and ``imu_only`` (1: the frame was posed by the IMU alone, vision
failed). ``vslam report`` plots them.

Example:
    >>> import numpy as np, tempfile, pathlib
    >>> f = pathlib.Path(tempfile.mkdtemp()) / "imu_states.csv"
    >>> _ = write_imu_states(f, [[1.0, 0.1, 0.2, 0.3, 0, 0, 0, 0, 0, 0, 0]])
    >>> read_imu_states(f)["vx"].tolist()
    [0.1]
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from vslam.errors import DatasetError
from vslam.outputs import atomic_write_text

COLUMNS = ("timestamp", "vx", "vy", "vz", "bgx", "bgy", "bgz", "bax", "bay", "baz", "imu_only")


def write_imu_states(path: str | Path, rows) -> Path:
    """Write ``rows`` (each ``len(COLUMNS)`` numbers) as ``imu_states.csv`` (atomically)."""
    lines = ["# " + ",".join(COLUMNS)]
    for r in rows:
        lines.append(f"{r[0]:.9f}," + ",".join(f"{float(v):.9g}" for v in r[1:10]) + f",{int(r[10])}")
    return atomic_write_text(path, "\n".join(lines) + "\n")


def read_imu_states(path: str | Path) -> dict[str, np.ndarray]:
    """``{column: (N,) array}`` of an ``imu_states.csv``; a malformed file is one :class:`DatasetError`."""
    path = Path(path)
    try:
        data = np.loadtxt(path, delimiter=",", comments="#", ndmin=2)
    except (OSError, ValueError) as exc:
        raise DatasetError(f"{path}: not an imu_states.csv ({exc})") from None
    if data.size and data.shape[1] != len(COLUMNS):
        raise DatasetError(f"{path}: {data.shape[1]} columns, expected {len(COLUMNS)} ({', '.join(COLUMNS)})")
    data = data.reshape(-1, len(COLUMNS))
    return {c: data[:, i] for i, c in enumerate(COLUMNS)}
