"""ATE of vslam and a baseline on the frames *both* tracked (issue 24).

A system that drops the hard part of a sequence (ORB-SLAM3 loses a quarter of monocular TUM, or all
but 15 frames of its monocular KITTI 07 map unpaced) would otherwise be scored on its easy frames
only. For each pair of rows of the same run and repeat (``run`` and ``run@system``), both
trajectories are cut to the timestamps they share (:func:`vslam.trajectory.associate_timestamps`,
within ``MAX_DIFF_S``) and each is scored against the ground truth on exactly those frames, with
its own alignment (Sim(3) for monocular, SE(3) otherwise, as the rows' own ATE).

The rows gain ``ate_common`` (m) and ``common_frames``; :mod:`vslam.bench.results` summarizes and
tabulates them next to the all-frames figures.
"""
from __future__ import annotations

import logging
from pathlib import Path
from typing import Sequence

import numpy as np

from vslam.errors import VslamError
from vslam.trajectory import Trajectory, associate_timestamps, read_trajectory

log = logging.getLogger(__name__)

MAX_DIFF_S = 1e-3  # both systems stamp a frame with the dataset's timestamp: equal up to print rounding
MIN_COMMON = 3  # an alignment needs at least 3 poses


def common_frame_ate(ours: Trajectory, theirs: Trajectory, gt: Trajectory, align: str) -> tuple[float, float, int]:
    """``(ATE ours, ATE theirs, n)`` on the ``n`` timestamps both trajectories have, each aligned to
    ``gt`` on those frames alone. Raises :class:`VslamError` with fewer than ``MIN_COMMON``."""
    from vslam.eval.evaluate import evaluate_trajectories

    i_ours, i_theirs = associate_timestamps(ours.timestamps, theirs.timestamps, MAX_DIFF_S)
    if len(i_ours) < MIN_COMMON:
        raise VslamError(f"only {len(i_ours)} frames tracked by both systems (need {MIN_COMMON})")
    a = evaluate_trajectories(ours.subset(i_ours), gt, align=align)
    b = evaluate_trajectories(theirs.subset(i_theirs), gt, align=align)
    n = min(a.matched_poses, b.matched_poses)
    return float(a.ate.rmse), float(b.ate.rmse), int(n)


def _ground_truth(row: dict) -> Trajectory | None:
    from vslam.datasets import open_dataset

    return open_dataset(row["data"], sensor=row.get("sensor")).ground_truth()


def add_common_frame_ate(rows: Sequence[dict], output: str | Path) -> None:
    """Fill ``ate_common`` / ``common_frames`` in place for every (vslam, baseline) row pair of one
    run and repeat that both succeeded; a pair that cannot be scored is logged and left without."""
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
            a, b, n = common_frame_ate(t_ours, t_base, gt, align)
        except (VslamError, OSError, ValueError) as exc:
            log.warning("%s repeat %s: no common-frame ATE (%s)", run, base.get("repeat"), exc)
            continue
        mine["ate_common"], mine["common_frames"] = a, n
        base["ate_common"], base["common_frames"] = b, n
        log.info("%s repeat %s: on the %d frames both tracked, ATE %.4f vs %.4f", run, base.get("repeat"), n, a, b)


def ratio(a: float | None, b: float | None) -> float | None:
    """``a / b`` or None."""
    if a is None or b is None or not np.isfinite(b) or b == 0:
        return None
    return a / b
