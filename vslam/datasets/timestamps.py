"""Timestamps: TUM-style ``timestamp field ...`` lists (checked sorted) and ground truth
interpolated at arbitrary times. Two lists are matched with :func:`vslam.trajectory.associate_timestamps`."""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from vslam.datasets.images import require_file
from vslam.errors import DatasetError
from vslam.geometry.lie import slerp_rotation
from vslam.textfile import open_text
from vslam.trajectory import Trajectory


#: a line starting ``1305031453,359684 `` (a decimal comma, then a space): not a CSV ``t,file`` line
_DECIMAL_COMMA = re.compile(r"^[+-]?\d+,\d+\s")


def check_timestamps(ts: np.ndarray, path: str | Path) -> None:
    """Raise unless ``ts`` is strictly increasing (names the first offending line/position)."""
    ts = np.asarray(ts, dtype=float)
    if not np.all(np.isfinite(ts)):
        raise DatasetError(f"{path}: timestamp {int(np.argmax(~np.isfinite(ts))) + 1} is not a finite number")
    d = np.diff(ts)
    if np.any(d == 0):
        i = int(np.argmax(d == 0))
        raise DatasetError(f"{path}: duplicate timestamp {ts[i]!r} (entries {i + 1} and {i + 2}); remove one")
    if np.any(d < 0):
        i = int(np.argmax(d < 0))
        raise DatasetError(
            f"{path}: timestamps are not sorted (entry {i + 2}, {ts[i + 1]!r}, is before {ts[i]!r}); sort the file"
        )


def read_timestamped_list(path: str | Path, what: str, min_columns: int = 2) -> tuple[np.ndarray, list[list[str]]]:
    """Read a TUM-style list (``timestamp field ...`` per line, ``#`` comments).

    Returns ``(timestamps (N,), rows)`` where ``rows[i]`` are the remaining fields of line i.
    Timestamps are kept as parsed (not sorted); use :func:`check_timestamps`.
    """
    path = require_file(path, what)
    ts: list[float] = []
    rows: list[list[str]] = []
    with open_text(path, DatasetError) as fh:
        for lineno, line in enumerate(fh, 1):
            line = line.strip()
            if not line or line.startswith("#"):
                continue
            if _DECIMAL_COMMA.match(line):
                stamp = line.split()[0]
                raise DatasetError(
                    f"{path}:{lineno}: timestamp {stamp!r} has a decimal comma; timestamps need a decimal point "
                    f"({stamp.replace(',', '.')}): rewrite the file with points (a spreadsheet's locale wrote commas)"
                )
            parts = line.replace(",", " ").split()
            if len(parts) < min_columns:
                raise DatasetError(
                    f"{path}:{lineno}: expected {min_columns} columns (timestamp filename ...), got {line[:80]!r}"
                )
            try:
                ts.append(float(parts[0]))
            except ValueError:
                raise DatasetError(f"{path}:{lineno}: timestamp {parts[0]!r} is not a number") from None
            rows.append(parts[1:])
    if not ts:
        raise DatasetError(f"{path}: the {what} has no entries")
    return np.array(ts, dtype=float), rows


def interpolate_poses(
    gt: Trajectory, t_query: np.ndarray, max_gap: float = 0.1, exact_tol: float = 1e-5
) -> tuple[np.ndarray, np.ndarray]:
    """Ground-truth poses at ``t_query`` (SLERP rotation, :func:`vslam.geometry.lie.slerp_rotation`,
    linear translation between neighbours).

    A query within ``exact_tol`` seconds of a GT sample takes that sample; otherwise it needs GT
    samples on both sides no more than ``max_gap`` seconds apart. Returns
    ``(T_world_cam (N, 4, 4), valid (N,) bool)``; invalid rows are NaN.
    """
    t_query = np.asarray(t_query, dtype=float).reshape(-1)
    n = len(t_query)
    T = np.full((n, 4, 4), np.nan)
    valid = np.zeros(n, dtype=bool)
    tg = gt.timestamps
    if len(tg) == 0 or n == 0:
        return T, valid
    idx = np.searchsorted(tg, t_query)  # tg[idx-1] < t <= tg[idx]
    # exact matches (nearest neighbour within exact_tol)
    left = np.clip(idx - 1, 0, len(tg) - 1)
    right = np.clip(idx, 0, len(tg) - 1)
    d_left = np.abs(t_query - tg[left])
    d_right = np.abs(t_query - tg[right])
    nearest = np.where(d_left <= d_right, left, right)
    exact = np.minimum(d_left, d_right) <= exact_tol
    T[exact] = gt.T_world_cam[nearest[exact]]
    valid[exact] = True
    # interpolation between neighbours
    inside = (~exact) & (idx > 0) & (idx < len(tg))
    if np.any(inside):
        i1 = idx[inside]
        i0 = i1 - 1
        gap = tg[i1] - tg[i0]
        ok = gap <= max_gap
        q_idx = np.flatnonzero(inside)[ok]
        i0, i1 = i0[ok], i1[ok]
        if len(q_idx):
            alpha = (t_query[q_idx] - tg[i0]) / (tg[i1] - tg[i0])
            Ti = np.tile(np.eye(4), (len(q_idx), 1, 1))
            Ti[:, :3, :3] = slerp_rotation(gt.T_world_cam[i0, :3, :3], gt.T_world_cam[i1, :3, :3], alpha)
            p0 = gt.T_world_cam[i0, :3, 3]
            p1 = gt.T_world_cam[i1, :3, 3]
            Ti[:, :3, 3] = p0 + alpha[:, None] * (p1 - p0)
            T[q_idx] = Ti
            valid[q_idx] = True
    return T, valid
