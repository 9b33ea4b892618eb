"""Trajectories (timestamped ``T_world_cam`` poses) and their file formats: TUM, KITTI, EuRoC CSV.

* TUM: ``timestamp tx ty tz qx qy qz qw`` per line, ``#`` comments.
* KITTI: 12 numbers per line, the row-major top 3x4 of ``T_world_cam``; timestamps from a
  separate ``times.txt`` (one per line) or, without one, the line index (0, 1, 2, ...).
* EuRoC ground truth CSV: ``#timestamp [ns], p_x, p_y, p_z, q_w, q_x, q_y, q_z, ...`` (extra
  columns ignored).

Every reader checks the file exists, has poses, has the right number of finite numbers on each
line, valid (non-zero) quaternions, strictly increasing timestamps, and magnitudes that float64
arithmetic can square and sum (coordinates within :data:`MAX_COORDINATE` metres, timestamps within
:data:`MAX_TIMESTAMP`); otherwise it raises :class:`~vslam.errors.TrajectoryError` naming the file,
the line and what to fix.
"""
from __future__ import annotations

import io
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from vslam.errors import TrajectoryError
from vslam.textfile import open_text

log = logging.getLogger(__name__)

FORMATS = ("tum", "kitti", "euroc")
#: |coordinate| above this (metres, a light-hour) is no trajectory: its squares and sums lose every
#: digit of a metre, and 1e200 overflows to inf in an RMSE
MAX_COORDINATE = 1e12
#: |timestamp| above this (seconds, or EuRoC's nanoseconds: 1e19 ns is the year 2286)
MAX_TIMESTAMP = 1e19


@dataclass
class Trajectory:
    """``timestamps (N,)`` seconds, strictly increasing, and ``T_world_cam (N, 4, 4)``."""

    timestamps: np.ndarray
    T_world_cam: np.ndarray

    def __post_init__(self) -> None:
        self.timestamps = np.asarray(self.timestamps, dtype=float).reshape(-1)
        T = np.asarray(self.T_world_cam, dtype=float)
        if T.size and T.shape[-2:] != (4, 4):
            raise TrajectoryError(f"trajectory poses must be (N, 4, 4) matrices, got shape {T.shape}")
        self.T_world_cam = T.reshape(-1, 4, 4)
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


def associate_timestamps(
    t_a: np.ndarray, t_b: np.ndarray, max_diff: float, offset: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs ``(i_a, i_b)`` with ``|t_a + offset - t_b| <= max_diff``, one-to-one, sorted by ``i_a``.

    Every candidate pair is sorted by that difference and accepted greedily, each timestamp used at
    most once: TUM's ``associate.py`` (Sturm et al., IROS 2012), which its ``evaluate_ate.py`` also
    uses. evo's ``sync.matching_time_indices`` (nearest neighbour of the shorter list) gives the
    same pairs whenever no timestamp is the nearest of two others; greedy then also pairs the
    loser with its next candidate. The one association of the project: RGB / depth / right image
    lists (datasets) and estimate / ground truth (evaluation). Candidates come from a sorted
    ``searchsorted`` window, so the cost is linear in the candidates, not ``len(t_a) * len(t_b)``.
    """
    a = np.asarray(t_a, dtype=float).reshape(-1) + offset
    b = np.asarray(t_b, dtype=float).reshape(-1)
    empty = (np.zeros(0, dtype=int), np.zeros(0, dtype=int))
    if len(a) == 0 or len(b) == 0:
        return empty
    order_b = np.argsort(b, kind="stable")
    bs = b[order_b]
    lo = np.searchsorted(bs, a - max_diff, side="left")
    hi = np.searchsorted(bs, a + max_diff, side="right")
    counts = hi - lo
    if counts.sum() == 0:
        return empty
    ia = np.repeat(np.arange(len(a)), counts)
    starts = np.repeat(lo - np.concatenate([[0], np.cumsum(counts)[:-1]]), counts)
    ib = order_b[starts + np.arange(counts.sum())]
    diff = np.abs(a[ia] - b[ib])
    keep = diff <= max_diff
    ia, ib, diff = ia[keep], ib[keep], diff[keep]
    used_a = np.zeros(len(a), dtype=bool)
    used_b = np.zeros(len(b), dtype=bool)
    pairs = []
    for k in np.argsort(diff, kind="stable"):
        i, j = ia[k], ib[k]
        if not used_a[i] and not used_b[j]:
            used_a[i] = used_b[j] = True
            pairs.append((i, j))
    out = np.array(sorted(pairs), dtype=int).reshape(-1, 2)
    return out[:, 0], out[:, 1]


def poses_from_tum_rows(rows: np.ndarray) -> np.ndarray:
    """``(N, 7)`` rows ``tx ty tz qx qy qz qw`` -> ``(N, 4, 4)`` poses (quaternions are normalised)."""
    rows = np.asarray(rows, dtype=float).reshape(-1, 7)
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


def _load_numeric(path: Path, delimiter: str | None, what: str) -> tuple[np.ndarray, np.ndarray]:
    """Numbers of every non-comment line -> ``(rows (N, W), line numbers (N,))``."""
    path = Path(path)
    if not path.is_file():
        raise TrajectoryError(f"{path}: {what} file not found" + (" (it is a directory)" if path.is_dir() else ""))
    rows: list[list[float]] = []
    linenos: list[int] = []
    try:
        with open_text(path, TrajectoryError) as fh:
            for lineno, line in enumerate(fh, 1):
                line = line.strip()
                if not line or line.startswith("#"):
                    continue
                parts = line.split(delimiter) if delimiter else line.replace(",", " ").split()
                try:
                    values = [float(p) for p in parts if p.strip() != ""]
                except ValueError:
                    raise TrajectoryError(
                        f"{path}:{lineno}: not a number in {what} line {line[:80]!r}"
                    ) from None
                if rows and len(values) != len(rows[0]):
                    raise TrajectoryError(
                        f"{path}:{lineno}: {what} line has {len(values)} numbers but the first line has "
                        f"{len(rows[0])}; fix or remove the malformed line"
                    )
                if not all(np.isfinite(values)):
                    raise TrajectoryError(f"{path}:{lineno}: NaN or inf in {what} line {line[:80]!r}")
                rows.append(values)
                linenos.append(lineno)
    except UnicodeDecodeError:
        raise TrajectoryError(f"{path}: not a text file; expected a {what} file") from None
    if not rows:
        raise TrajectoryError(f"{path}: the {what} file is empty (no poses)")
    return np.array(rows, dtype=float), np.array(linenos)


def _check_magnitude(values: np.ndarray, limit: float, what: str, path: Path, linenos: np.ndarray | None) -> None:
    """Raise naming the first line whose ``values`` row (or value) exceeds ``limit`` in magnitude."""
    values = np.abs(np.asarray(values, dtype=float))
    bad = values.reshape(len(values), -1).max(axis=1) > limit if len(values) else np.zeros(0, bool)
    if np.any(bad):
        i = int(np.argmax(bad))
        line = int(linenos[i]) if linenos is not None else i + 1
        raise TrajectoryError(f"{path}:{line}: {what} of magnitude {float(values[i].max()):.3g} is implausible (at most "
                              f"{limit:.0e}); fix the line or its units")


def _check_sorted(
    ts: np.ndarray, path: Path, linenos: np.ndarray | None = None, duplicates: str = "error"
) -> np.ndarray:
    """Raise unless ``ts`` is strictly increasing (and each within :data:`MAX_TIMESTAMP`); returns
    the indices of the rows to keep.

    ``duplicates="keep_last"`` drops all but the last of equal timestamps (what the TUM
    benchmark tools do when they read a file into a dict), instead of raising.
    """
    if duplicates not in ("error", "keep_last"):
        raise TrajectoryError(f"duplicates must be 'error' or 'keep_last', got {duplicates!r}")
    _check_magnitude(ts, MAX_TIMESTAMP, "a timestamp", path, linenos)
    d = np.diff(ts)
    line = (lambda i: int(linenos[i])) if linenos is not None else (lambda i: i + 1)
    if np.any(d < 0):
        i = int(np.argmax(d < 0)) + 1
        raise TrajectoryError(
            f"{path}:{line(i)}: timestamps are not sorted (timestamp {float(ts[i])!r} goes back in time); "
            "sort the file by time"
        )
    keep = np.ones(len(ts), dtype=bool)
    if np.any(d == 0):
        if duplicates == "error":
            i = int(np.argmax(d == 0)) + 1
            raise TrajectoryError(
                f"{path}:{line(i)}: duplicate timestamp {float(ts[i])!r} (same as the line before); remove "
                "the repeated pose, or keep the last one (--duplicates keep-last, duplicates='keep_last')"
            )
        keep[:-1] = d != 0
        log.warning("%s: dropped %d poses with duplicate timestamps (kept the last)", path, int(np.sum(~keep)))
    return np.flatnonzero(keep)


def _quats_to_matrices(q_xyzw: np.ndarray, path: Path, linenos: np.ndarray) -> np.ndarray:
    norms = np.linalg.norm(q_xyzw, axis=1)
    bad = norms < 1e-9
    if np.any(bad):
        raise TrajectoryError(f"{path}:{int(linenos[np.argmax(bad)])}: zero quaternion; a rotation needs |q| > 0")
    return Rotation.from_quat(q_xyzw).as_matrix()


def read_tum(path: str | Path, duplicates: str = "error") -> Trajectory:
    """Read a TUM trajectory (``timestamp tx ty tz qx qy qz qw``)."""
    path = Path(path)
    data, linenos = _load_numeric(path, None, "TUM trajectory")
    if data.shape[1] != 8:
        raise TrajectoryError(
            f"{path}: TUM lines need 8 numbers (t tx ty tz qx qy qz qw), found {data.shape[1]}"
            + ("; this looks like a KITTI file (use the kitti format)" if data.shape[1] == 12 else "")
        )
    keep = _check_sorted(data[:, 0], path, linenos, duplicates)
    data, linenos = data[keep], linenos[keep]
    _check_magnitude(data[:, 1:4], MAX_COORDINATE, "a position (metres)", path, linenos)
    T = np.tile(np.eye(4), (len(data), 1, 1))
    T[:, :3, :3] = _quats_to_matrices(data[:, 4:8], path, linenos)
    T[:, :3, 3] = data[:, 1:4]
    return Trajectory(data[:, 0], T)


def _writable(path: str | Path) -> Path:
    path = Path(path)
    if not path.parent.is_dir():
        raise TrajectoryError(f"{path}: cannot write the trajectory, folder {path.parent} does not exist")
    return path


def write_tum(path: str | Path, traj: Trajectory) -> None:
    """Write ``traj`` as a TUM file, atomically (:func:`vslam.outputs.atomic_write_text`)."""
    from vslam.outputs import atomic_write_text

    rows = tum_rows_from_poses(traj.T_world_cam)
    lines = ["# timestamp tx ty tz qx qy qz qw\n"] + [format_tum_line(t, r) for t, r in zip(traj.timestamps, rows)]
    atomic_write_text(_writable(path), "".join(lines))


def format_tum_line(timestamp: float, row: np.ndarray) -> str:
    """One TUM line for a timestamp and a ``(7,)`` row ``tx ty tz qx qy qz qw``."""
    return f"{timestamp:.6f} " + " ".join(f"{v:.9f}" for v in row) + "\n"


def read_kitti(
    path: str | Path, times: str | Path | np.ndarray | None = None, duplicates: str = "error"
) -> Trajectory:
    """Read KITTI poses (12 numbers per line); timestamps from ``times`` (file or array) or the index.

    Without ``times`` the timestamps are the line indices 0, 1, 2, ... (seconds), so two KITTI
    files without times are associated frame by frame.
    """
    path = Path(path)
    data, linenos = _load_numeric(path, None, "KITTI poses")
    if data.shape[1] != 12:
        raise TrajectoryError(
            f"{path}: KITTI lines need 12 numbers (3x4 row-major), found {data.shape[1]}"
            + ("; this looks like a TUM file (use the tum format)" if data.shape[1] == 8 else "")
        )
    _check_magnitude(data, MAX_COORDINATE, "a pose entry (metres)", path, linenos)
    T = np.tile(np.eye(4), (len(data), 1, 1))
    T[:, :3, :4] = data.reshape(-1, 3, 4)
    if times is None:
        ts = np.arange(len(data), dtype=float)
    else:
        if isinstance(times, (str, Path)):
            tdata, tlines = _load_numeric(Path(times), None, "KITTI times")
            ts, where = tdata[:, 0], Path(times)
        else:
            ts, tlines, where = np.asarray(times, dtype=float).reshape(-1), None, Path(f"{path} times")
        if len(ts) < len(data):
            raise TrajectoryError(
                f"{path}: {len(data)} poses but only {len(ts)} timestamps in {times if isinstance(times, (str, Path)) else 'the times array'}"
            )
        ts = ts[: len(data)]
        keep = _check_sorted(ts, where, None if tlines is None else tlines[: len(data)], duplicates)
        ts, T = ts[keep], T[keep]
    return Trajectory(ts, T)


def write_kitti(path: str | Path, traj: Trajectory, times_path: str | Path | None = None) -> None:
    """Write ``traj`` as KITTI poses (and its times), atomically."""
    from vslam.outputs import atomic_write_text

    def text(array: np.ndarray, fmt: str) -> str:
        buf = io.StringIO()
        np.savetxt(buf, array, fmt=fmt)
        return buf.getvalue()

    atomic_write_text(_writable(path), text(traj.T_world_cam[:, :3, :4].reshape(-1, 12), "%.9e"))
    if times_path is not None:
        atomic_write_text(_writable(times_path), text(traj.timestamps, "%.6f"))


def read_euroc(path: str | Path, duplicates: str = "error") -> Trajectory:
    """Read an EuRoC ground-truth CSV (``t[ns], px, py, pz, qw, qx, qy, qz, ...``)."""
    path = Path(path)
    data, linenos = _load_numeric(path, ",", "EuRoC CSV")
    if data.shape[1] < 8:
        raise TrajectoryError(f"{path}: EuRoC CSV rows need >= 8 columns (t, p xyz, q wxyz), found {data.shape[1]}")
    keep = _check_sorted(data[:, 0], path, linenos, duplicates)
    data, linenos = data[keep], linenos[keep]
    _check_magnitude(data[:, 1:4], MAX_COORDINATE, "a position (metres)", path, linenos)
    ts = data[:, 0] * 1e-9
    T = np.tile(np.eye(4), (len(data), 1, 1))
    T[:, :3, :3] = _quats_to_matrices(np.hstack([data[:, 5:8], data[:, 4:5]]), path, linenos)
    T[:, :3, 3] = data[:, 1:4]
    return Trajectory(ts, T)


def write_euroc(path: str | Path, traj: Trajectory) -> None:
    """Write ``traj`` as a EuRoC CSV, atomically."""
    from vslam.outputs import atomic_write_text

    rows = tum_rows_from_poses(traj.T_world_cam)
    lines = ["#timestamp [ns],p_x [m],p_y [m],p_z [m],q_w [],q_x [],q_y [],q_z []\n"]
    for t, r in zip(traj.timestamps, rows):
        vals = [r[0], r[1], r[2], r[6], r[3], r[4], r[5]]
        lines.append(f"{int(round(t * 1e9))}," + ",".join(f"{v:.9f}" for v in vals) + "\n")
    atomic_write_text(_writable(path), "".join(lines))


def detect_format(path: str | Path) -> str:
    """Guess ``tum``, ``kitti`` or ``euroc`` from the first data line.

    A comma-separated line is EuRoC, 12 numbers is KITTI, anything else TUM.
    """
    path = Path(path)
    if not path.is_file():
        raise TrajectoryError(f"{path}: trajectory file not found")
    first = ""
    try:
        with open_text(path, TrajectoryError) as fh:
            for line in fh:
                if line.strip() and not line.lstrip().startswith("#"):
                    first = line
                    break
    except UnicodeDecodeError:
        raise TrajectoryError(f"{path}: not a text file; expected a TUM, KITTI or EuRoC trajectory") from None
    if not first:
        raise TrajectoryError(f"{path}: the trajectory file is empty (no poses)")
    if "," in first:
        return "euroc"
    if len(first.split()) == 12:
        return "kitti"
    return "tum"


def read_trajectory(
    path: str | Path, fmt: str | None = None, times: str | Path | None = None, duplicates: str = "error"
) -> Trajectory:
    """Read a trajectory, detecting the format from the content when ``fmt`` is None.

    ``fmt`` is one of ``tum``, ``kitti``, ``euroc``; ``times`` is only used for KITTI;
    ``duplicates`` is ``error`` (default) or ``keep_last`` for repeated timestamps.
    """
    path = Path(path)
    if fmt is None:
        fmt = detect_format(path)
    if fmt == "tum":
        return read_tum(path, duplicates)
    if fmt == "kitti":
        return read_kitti(path, times, duplicates)
    if fmt == "euroc":
        return read_euroc(path, duplicates)
    raise TrajectoryError(f"unknown trajectory format {fmt!r} (use tum, kitti or euroc)")


def write_trajectory(path: str | Path, traj: Trajectory, fmt: str = "tum", times_path: str | Path | None = None) -> None:
    """Write ``traj`` as ``tum``, ``kitti`` (optionally with ``times_path``) or ``euroc``."""
    if fmt == "tum":
        write_tum(path, traj)
    elif fmt == "kitti":
        write_kitti(path, traj, times_path)
    elif fmt == "euroc":
        write_euroc(path, traj)
    else:
        raise TrajectoryError(f"unknown trajectory format {fmt!r} (use tum, kitti or euroc)")
