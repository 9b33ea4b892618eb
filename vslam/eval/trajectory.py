"""Trajectories (timestamped ``T_world_cam`` poses) and their file formats: TUM, KITTI, EuRoC CSV.

* TUM: ``timestamp tx ty tz qx qy qz qw`` per line, ``#`` comments.
* KITTI: 12 numbers per line, the row-major top 3x4 of ``T_world_cam``; timestamps from a
  separate ``times.txt`` (one per line) or the line index.
* EuRoC ground truth CSV: ``#timestamp [ns], p_x, p_y, p_z, q_w, q_x, q_y, q_z, ...`` (extra
  columns ignored).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from vslam.errors import TrajectoryError


@dataclass
class Trajectory:
    """``timestamps (N,)`` seconds, strictly increasing, and ``T_world_cam (N, 4, 4)``."""

    timestamps: np.ndarray
    T_world_cam: np.ndarray

    def __post_init__(self) -> None:
        self.timestamps = np.asarray(self.timestamps, dtype=float).reshape(-1)
        self.T_world_cam = np.asarray(self.T_world_cam, dtype=float).reshape(-1, 4, 4)
        if len(self.timestamps) != len(self.T_world_cam):
            raise TrajectoryError(
                f"trajectory has {len(self.timestamps)} timestamps but {len(self.T_world_cam)} poses"
            )

    def __len__(self) -> int:
        return len(self.timestamps)

    @property
    def positions(self) -> np.ndarray:
        """Camera centres ``(N, 3)`` in the world frame."""
        return self.T_world_cam[:, :3, 3]

    def subset(self, index: np.ndarray) -> "Trajectory":
        return Trajectory(self.timestamps[index], self.T_world_cam[index])


def poses_from_tum_rows(rows: np.ndarray) -> np.ndarray:
    """``(N, 7)`` rows ``tx ty tz qx qy qz qw`` -> ``(N, 4, 4)`` poses."""
    T = np.tile(np.eye(4), (len(rows), 1, 1))
    if len(rows):
        T[:, :3, :3] = Rotation.from_quat(rows[:, 3:7]).as_matrix()
        T[:, :3, 3] = rows[:, :3]
    return T


def tum_rows_from_poses(T_world_cam: np.ndarray) -> np.ndarray:
    """``(N, 4, 4)`` poses -> ``(N, 7)`` rows ``tx ty tz qx qy qz qw``."""
    T_world_cam = np.asarray(T_world_cam).reshape(-1, 4, 4)
    if len(T_world_cam) == 0:
        return np.zeros((0, 7))
    q = Rotation.from_matrix(T_world_cam[:, :3, :3]).as_quat()
    return np.hstack([T_world_cam[:, :3, 3], q])


def _load_numeric(path: Path, delimiter: str | None, what: str) -> np.ndarray:
    path = Path(path)
    if not path.is_file():
        raise TrajectoryError(f"{path}: {what} file not found")
    rows = []
    with open(path, encoding="utf-8-sig") as fh:
        for lineno, line in enumerate(fh, 1):
            line = line.strip()
            if not line or line.startswith("#"):
                continue
            parts = line.split(delimiter) if delimiter else line.replace(",", " ").split()
            try:
                rows.append([float(p) for p in parts if p.strip() != ""])
            except ValueError:
                raise TrajectoryError(f"{path}:{lineno}: not a number in {what} line: {line[:80]!r}") from None
    if not rows:
        raise TrajectoryError(f"{path}: the {what} file has no poses")
    width = len(rows[0])
    for i, r in enumerate(rows):
        if len(r) != width:
            raise TrajectoryError(f"{path}: {what} rows have {width} and {len(r)} columns (row {i + 1})")
    return np.array(rows, dtype=float)


def _check_sorted(ts: np.ndarray, path: Path) -> None:
    d = np.diff(ts)
    if np.any(d < 0):
        i = int(np.argmax(d < 0))
        raise TrajectoryError(f"{path}: timestamps are not sorted (line {i + 2} goes back in time)")
    if np.any(d == 0):
        i = int(np.argmax(d == 0))
        raise TrajectoryError(f"{path}: duplicate timestamp {ts[i]!r}; remove the repeated pose")


def read_tum(path: str | Path) -> Trajectory:
    """Read a TUM trajectory (``timestamp tx ty tz qx qy qz qw``)."""
    path = Path(path)
    data = _load_numeric(path, None, "TUM trajectory")
    if data.shape[1] != 8:
        raise TrajectoryError(f"{path}: TUM lines need 8 numbers (t tx ty tz qx qy qz qw), found {data.shape[1]}")
    _check_sorted(data[:, 0], path)
    return Trajectory(data[:, 0], poses_from_tum_rows(data[:, 1:]))


def write_tum(path: str | Path, traj: Trajectory) -> None:
    rows = tum_rows_from_poses(traj.T_world_cam)
    with open(path, "w") as fh:
        fh.write("# timestamp tx ty tz qx qy qz qw\n")
        for t, r in zip(traj.timestamps, rows):
            fh.write(format_tum_line(t, r))


def format_tum_line(timestamp: float, row: np.ndarray) -> str:
    """One TUM line for a timestamp and a ``(7,)`` row ``tx ty tz qx qy qz qw``."""
    return f"{timestamp:.6f} " + " ".join(f"{v:.9f}" for v in row) + "\n"


def read_kitti(path: str | Path, times: str | Path | np.ndarray | None = None) -> Trajectory:
    """Read KITTI poses (12 numbers per line); timestamps from ``times`` (file or array) or the index."""
    path = Path(path)
    data = _load_numeric(path, None, "KITTI poses")
    if data.shape[1] != 12:
        raise TrajectoryError(f"{path}: KITTI lines need 12 numbers (3x4 row-major), found {data.shape[1]}")
    T = np.tile(np.eye(4), (len(data), 1, 1))
    T[:, :3, :4] = data.reshape(-1, 3, 4)
    if times is None:
        ts = np.arange(len(data), dtype=float)
    else:
        ts = np.asarray(times, dtype=float).reshape(-1) if not isinstance(times, (str, Path)) else \
            _load_numeric(Path(times), None, "KITTI times")[:, 0]
        if len(ts) < len(data):
            raise TrajectoryError(f"{path}: {len(data)} poses but only {len(ts)} timestamps in {times}")
        ts = ts[: len(data)]
    _check_sorted(ts, path)
    return Trajectory(ts, T)


def write_kitti(path: str | Path, traj: Trajectory, times_path: str | Path | None = None) -> None:
    np.savetxt(path, traj.T_world_cam[:, :3, :4].reshape(-1, 12), fmt="%.9e")
    if times_path is not None:
        np.savetxt(times_path, traj.timestamps, fmt="%.6e")


def read_euroc(path: str | Path) -> Trajectory:
    """Read an EuRoC ground-truth CSV (``t[ns], px, py, pz, qw, qx, qy, qz, ...``)."""
    path = Path(path)
    data = _load_numeric(path, ",", "EuRoC CSV")
    if data.shape[1] < 8:
        raise TrajectoryError(f"{path}: EuRoC CSV rows need >= 8 columns (t, p xyz, q wxyz), found {data.shape[1]}")
    ts = data[:, 0] * 1e-9
    _check_sorted(ts, path)
    rows = np.hstack([data[:, 1:4], data[:, 5:8], data[:, 4:5]])  # -> tx ty tz qx qy qz qw
    return Trajectory(ts, poses_from_tum_rows(rows))


def write_euroc(path: str | Path, traj: Trajectory) -> None:
    rows = tum_rows_from_poses(traj.T_world_cam)
    with open(path, "w") as fh:
        fh.write("#timestamp [ns],p_x [m],p_y [m],p_z [m],q_w [],q_x [],q_y [],q_z []\n")
        for t, r in zip(traj.timestamps, rows):
            vals = [r[0], r[1], r[2], r[6], r[3], r[4], r[5]]
            fh.write(f"{int(round(t * 1e9))}," + ",".join(f"{v:.9f}" for v in vals) + "\n")


def read_trajectory(path: str | Path, fmt: str | None = None, times: str | Path | None = None) -> Trajectory:
    """Read a trajectory, detecting the format from the content when ``fmt`` is None.

    ``fmt`` is one of ``tum``, ``kitti``, ``euroc``. Detection: a comma-separated file is EuRoC,
    12 columns is KITTI, 8 columns is TUM.
    """
    path = Path(path)
    if fmt is None:
        if not path.is_file():
            raise TrajectoryError(f"{path}: trajectory file not found")
        first = ""
        with open(path, encoding="utf-8-sig") as fh:
            for line in fh:
                if line.strip() and not line.lstrip().startswith("#"):
                    first = line
                    break
        if not first:
            raise TrajectoryError(f"{path}: the trajectory file has no poses")
        if "," in first:
            fmt = "euroc"
        elif len(first.split()) == 12:
            fmt = "kitti"
        else:
            fmt = "tum"
    if fmt == "tum":
        return read_tum(path)
    if fmt == "kitti":
        return read_kitti(path, times)
    if fmt == "euroc":
        return read_euroc(path)
    raise TrajectoryError(f"unknown trajectory format {fmt!r} (use tum, kitti or euroc)")
