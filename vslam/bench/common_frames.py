"""ATE of vslam and a baseline on the frames *both* tracked (issue 24).

A system that drops the hard part of a sequence (ORB-SLAM3 loses a quarter of monocular TUM, or all
but 15 frames of its monocular KITTI 07 map unpaced) would otherwise be scored on its easy frames
only. For each pair of rows of the same run and repeat (``run`` and ``run@system``), both
trajectories are cut to the timestamps they share (:func:`vslam.trajectory.associate_timestamps`,
within ``MAX_DIFF_S``) and each is scored against the ground truth on exactly those frames, with
its own alignment (Sim(3) for monocular, SE(3) otherwise, as the rows' own ATE).

On the same frames the two error vectors (each system's aligned position minus the ground truth's)
are also compared: ``ate_between``, the RMS distance between the two aligned trajectories
(``sqrt(mean |e_ours - e_theirs|^2)``), and ``error_correlation``, ``mean(e_ours . e_theirs) /
(ATE_ours ATE_theirs)``. A correlation near 1 with a small distance says both systems make the same
error there (it sits in the ground truth, the calibration or the sequence, not in either system),
so an ATE ratio near 1 on such a row says little about which system is better. Measured
(``benchmarks/RESULTS.md`` round 12): MH_01 stereo, 1.4 mm apart with 3.0 mm ATE each, correlation
0.89; KITTI 07 mono, 5 cm apart with 0.30 m each, correlation 0.99.

The rows gain ``ate_common`` (m), ``common_frames``, ``ate_between`` (m) and ``error_correlation``;
:mod:`vslam.bench.results` summarizes and tabulates them next to the all-frames figures.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from vslam.errors import VslamError
from vslam.trajectory import Trajectory, associate_timestamps, read_trajectory

log = logging.getLogger(__name__)

MAX_DIFF_S = 1e-3  # both systems stamp a frame with the dataset's timestamp: equal up to print rounding
MIN_COMMON = 3  # an alignment needs at least 3 poses


@dataclass(frozen=True)
class CommonFrames:
    """Both systems scored on the ``frames`` timestamps they share (module docstring): ``ours`` and
    ``theirs`` ATE RMSE (m), ``between`` the RMS distance between the two aligned trajectories (m) and
    ``correlation`` of their per-frame position errors (None when either error is zero)."""

    ours: float
    theirs: float
    frames: int
    between: float
    correlation: float | None


def common_frame_ate(ours: Trajectory, theirs: Trajectory, gt: Trajectory, align: str) -> CommonFrames:
    """Both trajectories on the timestamps both have, each aligned to ``gt`` on those frames alone.
    Raises :class:`VslamError` with fewer than ``MIN_COMMON``."""
    from vslam.eval.evaluate import evaluate_trajectories

    i_ours, i_theirs = associate_timestamps(ours.timestamps, theirs.timestamps, MAX_DIFF_S)
    if len(i_ours) < MIN_COMMON:
        raise VslamError(f"only {len(i_ours)} frames tracked by both systems (need {MIN_COMMON})")
    a = evaluate_trajectories(ours.subset(i_ours), gt, align=align)
    b = evaluate_trajectories(theirs.subset(i_theirs), gt, align=align)
    n = min(a.matched_poses, b.matched_poses)
    # the error vectors on the ground-truth poses both were matched to
    j_a, j_b = associate_timestamps(a.gt_matched.timestamps, b.gt_matched.timestamps, MAX_DIFF_S)
    if not len(j_a):
        return CommonFrames(float(a.ate.rmse), float(b.ate.rmse), int(n), float("nan"), None)
    e_a, e_b = _position_errors(a)[j_a], _position_errors(b)[j_b]
    norm = _rms(e_a) * _rms(e_b)
    corr = float(np.mean(np.sum(e_a * e_b, axis=1)) / norm) if norm > 0 else None
    return CommonFrames(float(a.ate.rmse), float(b.ate.rmse), int(n), _rms(e_a - e_b), corr)


def _rms(e: np.ndarray) -> float:
    """RMS length of the rows of ``e``."""
    return float(np.sqrt(np.mean(np.sum(e**2, axis=1))))


def _position_errors(result) -> np.ndarray:
    """Per matched pose: aligned estimated position minus ground-truth position, ``(n, 3)``."""
    return result.est_aligned.T_world_cam[:, :3, 3] - result.gt_matched.T_world_cam[:, :3, 3]


def _ground_truth(row: dict) -> Trajectory | None:
    from vslam.datasets import open_dataset

    return open_dataset(row["data"], sensor=row.get("sensor")).ground_truth()


def add_common_frame_ate(rows: Sequence[dict], output: str | Path) -> None:
    """Fill ``ate_common`` / ``common_frames`` / ``ate_between`` / ``error_correlation`` in place for
    every (vslam, baseline) row pair of one run and repeat that both succeeded; a pair that cannot be
    scored is logged and left without."""
    output = Path(output)
    ours = {(r["name"], r["repeat"]): r for r in rows if r.get("system", "vslam") == "vslam"}
    gt_cache: dict[str, Trajectory | None] = {}
    for base in rows:
        run, sep, _system = base["name"].rpartition("@")
        mine = ours.get((run, base.get("repeat")))
        if not sep or base.get("system", "vslam") == "vslam" or mine is None:
            continue
        if base.get("status") != "ok" or mine.get("status") != "ok":
            continue
        try:
            if mine["data"] not in gt_cache:
                gt_cache[mine["data"]] = _ground_truth(mine)
            gt = gt_cache[mine["data"]]
            if gt is None:
                continue
            t_ours = read_trajectory(output / mine["output"] / "trajectory.txt")
            t_base = read_trajectory(output / base["output"] / "trajectory.txt")
            align = "sim3" if mine.get("sensor") == "mono" else "se3"
            c = common_frame_ate(t_ours, t_base, gt, align)
        except (VslamError, OSError, ValueError) as exc:
            log.warning("%s repeat %s: no common-frame ATE (%s)", run, base.get("repeat"), exc)
            continue
        for row, ate in ((mine, c.ours), (base, c.theirs)):
            row.update(ate_common=ate, common_frames=c.frames, ate_between=c.between, error_correlation=c.correlation)
        log.info("%s repeat %s: on the %d frames both tracked, ATE %.4f vs %.4f, %.4f apart (error correlation %s)",
                 run, base.get("repeat"), c.frames, c.ours, c.theirs, c.between,
                 "-" if c.correlation is None else f"{c.correlation:.2f}")


def ratio(a: float | None, b: float | None) -> float | None:
    """``a / b`` or None."""
    if a is None or b is None or not np.isfinite(b) or b == 0:
        return None
    return a / b
