"""One call from two trajectories to every number: association, alignment, ATE, RPE, KITTI metric.

>>> from vslam.eval import evaluate_files
>>> result = evaluate_files("est.txt", "groundtruth.txt", align="sim3")   # doctest: +SKIP
>>> result.ate.rmse, result.scale, result.to_dict()["rpe_trans_rmse"]      # doctest: +SKIP
"""
from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from vslam.errors import TrajectoryError
from vslam.eval.associate import associate_trajectories
from vslam.eval.kitti_metric import KittiResult, kitti_odometry_error
from vslam.eval.metrics import (
    Alignment, ErrorStats, align, ate_errors, ate_rotation_errors_deg, rpe_errors, rpe_pairs,
)
from vslam.trajectory import Trajectory, detect_format, read_trajectory

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class EvalConfig:
    """How to compare an estimate with ground truth.

    Attributes:
        align: ``se3`` (default), ``sim3`` (monocular), ``none``, ``scale`` or ``origin``.
        align_first: estimate the alignment from the first N matched poses only (None: all).
        max_diff: association tolerance in seconds.
        offset: seconds added to the estimate's timestamps before association.
        by_index: pair poses by index instead of time (KITTI files without timestamps).
        rpe_delta, rpe_delta_unit: RPE step, in ``frames`` or ``m`` of travelled path.
        rpe_all_pairs: every start index instead of consecutive, non-overlapping pairs.
        rpe_pairs_from_gt: choose RPE pairs on the ground truth path (default: on the estimate, as evo).
        kitti: also compute the KITTI odometry metric; kitti_lengths its segment lengths (m).
    """

    align: str = "se3"
    align_first: int | None = None
    max_diff: float = 0.01
    offset: float = 0.0
    by_index: bool = False
    rpe_delta: float = 1
    rpe_delta_unit: str = "frames"
    rpe_all_pairs: bool = False
    rpe_pairs_from_gt: bool = False
    kitti: bool = False
    kitti_lengths: tuple[float, ...] | None = None
    kitti_step: int = 10


@dataclass
class EvalResult:
    """Everything :func:`evaluate_trajectories` measured.

    ``est_aligned`` and ``gt_matched`` are the associated poses (estimate after alignment);
    ``ate_errors`` is per matched pose, ``rpe_trans_errors``/``rpe_rot_errors_deg`` per pair.
    """

    config: EvalConfig
    est_poses: int
    gt_poses: int
    matched_poses: int
    alignment: Alignment
    ate: ErrorStats
    ate_rot_deg: ErrorStats
    rpe_trans: ErrorStats
    rpe_rot_deg: ErrorStats
    est_aligned: Trajectory
    gt_matched: Trajectory
    ate_errors: np.ndarray
    rpe_pairs: np.ndarray
    rpe_trans_errors: np.ndarray
    rpe_rot_errors_deg: np.ndarray
    kitti: KittiResult | None = None
    names: tuple[str, str] = ("estimate", "ground truth")
    extra: dict = field(default_factory=dict)

    @property
    def scale(self) -> float:
        """Scale of the Sim(3) alignment (1 for the other modes)."""
        return self.alignment.s

    @property
    def ate_rmse(self) -> float:
        return self.ate.rmse

    def to_dict(self) -> dict:
        """Flat JSON-ready summary (``ate_rmse``, ``rpe_trans_rmse``, ``rpe_rot_deg_rmse``, ...)."""
        c = self.config
        d: dict = {
            "estimate": self.names[0],
            "ground_truth": self.names[1],
            "est_poses": self.est_poses,
            "gt_poses": self.gt_poses,
            "matched_poses": self.matched_poses,
            "alignment": self.alignment.mode,
            "align_first": c.align_first,
            "scale": self.scale,
            "T_gt_est": self.alignment.T_gt_est.tolist(),
            "max_diff": c.max_diff,
            "offset": c.offset,
            "associated_by": "index" if c.by_index else "time",
            "duration_s": float(self.gt_matched.timestamps[-1] - self.gt_matched.timestamps[0]),
            "rpe_delta": c.rpe_delta,
            "rpe_delta_unit": c.rpe_delta_unit,
            "rpe_all_pairs": c.rpe_all_pairs,
            "rpe_pairs": int(len(self.rpe_pairs)),
        }
        for prefix, stats in (("ate", self.ate), ("ate_rot_deg", self.ate_rot_deg),
                              ("rpe_trans", self.rpe_trans), ("rpe_rot_deg", self.rpe_rot_deg)):
            for key in ("rmse", "mean", "median", "std", "min", "max"):
                d[f"{prefix}_{key}"] = getattr(stats, key)
        if self.kitti is not None:
            d["kitti_t_err_percent"] = self.kitti.t_err_percent
            d["kitti_r_err_deg_per_100m"] = self.kitti.r_err_deg_per_100m
            d["kitti"] = self.kitti.to_dict()
        d.update(self.extra)
        return d

    def summary(self) -> str:
        """Human-readable multi-line report (what ``vslam eval`` prints)."""
        c = self.config
        unit = "frames" if c.rpe_delta_unit in ("frames", "f") else "m"
        lines = [
            f"estimate:      {self.names[0]} ({self.est_poses} poses)",
            f"ground truth:  {self.names[1]} ({self.gt_poses} poses)",
            f"matched poses: {self.matched_poses} (by {'index' if c.by_index else f'time, max diff {c.max_diff} s'})",
            f"alignment:     {self.alignment.mode}"
            + (f" on first {c.align_first}" if c.align_first else "") + f", scale {self.scale:.6f}",
            "",
            f"{'':18s}{'rmse':>10s}{'mean':>10s}{'median':>10s}{'std':>10s}{'max':>10s}",
        ]
        for name, st in (("ATE (m)", self.ate), ("ATE rot (deg)", self.ate_rot_deg),
                         ("RPE trans (m)", self.rpe_trans), ("RPE rot (deg)", self.rpe_rot_deg)):
            lines.append(f"{name:18s}{st.rmse:10.5f}{st.mean:10.5f}{st.median:10.5f}{st.std:10.5f}{st.max:10.5f}")
        lines.append(f"RPE: {len(self.rpe_pairs)} pairs, delta {c.rpe_delta:g} {unit}"
                     + (" (all pairs)" if c.rpe_all_pairs else ""))
        if self.kitti is not None:
            k = self.kitti
            lines.append(f"KITTI: t_err {k.t_err_percent:.4f} %, r_err {k.r_err_deg_per_100m:.4f} deg/100m "
                         f"({k.num_segments} segments of {', '.join(f'{x:g}' for x in k.lengths)} m)")
        return "\n".join(lines)


def evaluate_trajectories(
    est: Trajectory,
    gt: Trajectory,
    config: EvalConfig | None = None,
    *,
    names: tuple[str, str] = ("estimate", "ground truth"),
    **overrides,
) -> EvalResult:
    """Associate, align and score ``est`` against ``gt`` (both ``T_world_cam``).

    ``overrides`` replace fields of ``config`` (e.g. ``align="sim3", max_diff=0.02``).
    RPE and the KITTI metric are computed on the aligned estimate (so Sim(3) fixes the scale).

    Raises:
        TrajectoryError: no common timestamps, too few poses to align, no RPE pair, ...
    """
    config = dataclasses.replace(config or EvalConfig(), **overrides)
    est_m, gt_m = associate_trajectories(est, gt, config.max_diff, config.offset, config.by_index, *names)
    n = len(est_m)
    log.info("matched %d of %d estimated and %d ground-truth poses", n, len(est), len(gt))
    if n < 2:
        raise TrajectoryError(
            f"only {n} pose of {names[0]} matches {names[1]}; need at least 2 (check timestamps, --max-diff)"
        )
    alignment = align(est_m.T_world_cam, gt_m.T_world_cam, config.align, config.align_first)
    T_est = alignment.apply(est_m.T_world_cam)
    T_gt = gt_m.T_world_cam
    ate = ate_errors(T_est, T_gt)
    pairs = rpe_pairs(T_gt if config.rpe_pairs_from_gt else T_est, config.rpe_delta,
                      config.rpe_delta_unit, config.rpe_all_pairs)
    if len(pairs) == 0:
        raise TrajectoryError(
            f"RPE delta {config.rpe_delta} {config.rpe_delta_unit} gives no pose pair on {n} matched poses; "
            "use a smaller --delta"
        )
    rpe_t, rpe_r = rpe_errors(T_est, T_gt, pairs)
    kitti = None
    if config.kitti:
        kitti = kitti_odometry_error(T_est, T_gt, config.kitti_lengths, config.kitti_step)
    return EvalResult(
        config=config, est_poses=len(est), gt_poses=len(gt), matched_poses=n, alignment=alignment,
        ate=ErrorStats.of(ate), ate_rot_deg=ErrorStats.of(ate_rotation_errors_deg(T_est, T_gt)),
        rpe_trans=ErrorStats.of(rpe_t), rpe_rot_deg=ErrorStats.of(rpe_r),
        est_aligned=Trajectory(est_m.timestamps, T_est), gt_matched=gt_m, ate_errors=ate,
        rpe_pairs=pairs, rpe_trans_errors=rpe_t, rpe_rot_errors_deg=rpe_r, kitti=kitti, names=names,
    )


def evaluate_files(
    est_path: str | Path,
    gt_path: str | Path,
    config: EvalConfig | None = None,
    *,
    est_format: str | None = None,
    gt_format: str | None = None,
    est_times: str | Path | None = None,
    gt_times: str | Path | None = None,
    duplicates: str = "error",
    gt_duplicates: str | None = None,
    gt_T_right: np.ndarray | None = None,
    **overrides,
) -> EvalResult:
    """Read two trajectory files (format detected unless given) and :func:`evaluate_trajectories`.

    A KITTI file without a times file has no timestamps: then both are associated by index
    (pose i with pose i; they must have the same length) unless ``by_index`` is given explicitly.
    ``duplicates="keep_last"`` accepts repeated timestamps (the official TUM fr2/desk ground truth
    has one), keeping the last pose of each; ``gt_duplicates`` sets it for the ground truth alone
    (default: as ``duplicates``). ``gt_T_right`` ``(4, 4)`` multiplies every ground-truth pose on the
    right: ``T_world_body @ T_body_cam`` turns body-frame ground truth (EuRoC's
    ``state_groundtruth_estimate0``) into the camera's.
    """
    est_format = est_format or detect_format(est_path)
    gt_format = gt_format or detect_format(gt_path)
    est = read_trajectory(est_path, est_format, est_times, duplicates)
    gt = read_trajectory(gt_path, gt_format, gt_times, gt_duplicates or duplicates)
    if gt_T_right is not None:
        gt = Trajectory(gt.timestamps, gt.T_world_cam @ np.asarray(gt_T_right, dtype=float))
    if "by_index" not in overrides and (config is None or not config.by_index):
        untimed = (est_format == "kitti" and est_times is None) or (gt_format == "kitti" and gt_times is None)
        if untimed:
            log.info("a KITTI file without times: associating poses by index")
            overrides["by_index"] = True
    return evaluate_trajectories(est, gt, config, names=(str(est_path), str(gt_path)), **overrides)
