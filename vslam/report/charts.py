"""The figures of a run report: the trajectory from above against ground truth (with the loop
closures), the position error along the path, the time per pipeline stage and the sparse map."""
from __future__ import annotations

import numpy as np

from vslam.report.page import new_figure, png_data_uri
from vslam.report.run_data import RunData, aligned_positions, loop_positions, lost_gaps, with_breaks


def top_axes(T_world_cam: np.ndarray | None, points: np.ndarray | None = None) -> tuple[int, int]:
    """The two world axes of a view "from above".

    Cameras in every supported dataset are held roughly upright (car, hand, MAV), so the world
    axis best aligned with the cameras' mean y (image-down) axis is the vertical; the other two are
    plotted. When no axis dominates (mean |component| < 0.5) fall back to the two axes of largest
    extent of the positions (or ``points``).
    """
    from vslam.eval.plot import top_view_axes

    if T_world_cam is not None and len(T_world_cam):
        down = np.mean(np.asarray(T_world_cam)[:, :3, 1], axis=0)
        if np.max(np.abs(down)) >= 0.5:
            vertical = int(np.argmax(np.abs(down)))
            a, b = (i for i in range(3) if i != vertical)
            return a, b
    pts = points if points is not None else (np.asarray(T_world_cam)[:, :3, 3] if T_world_cam is not None else None)
    return top_view_axes(pts) if pts is not None and len(pts) >= 2 else (0, 1)


def axis_unit(run: RunData, aligned: bool) -> str:
    """``m``, or ``arbitrary scale`` for a monocular run's own frame (not Sim(3)-aligned to ground truth)."""
    return "arbitrary scale" if run.stats.get("sensor") == "mono" and not aligned else "m"


def gt_span(run: RunData):
    """The ground truth over the estimate's time span (plus one frame either side)."""
    gt = run.gt
    if gt is None or run.est is None or len(run.est) == 0 or len(gt) < 2:
        return gt
    slack = float(np.median(np.diff(gt.timestamps)))
    keep = (gt.timestamps >= run.est.timestamps[0] - slack) & (gt.timestamps <= run.est.timestamps[-1] + slack)
    return gt.subset(np.flatnonzero(keep)) if keep.sum() >= 2 else gt


def plot_trajectory(run: RunData) -> str | None:
    """Top view: ground truth, the aligned estimate coloured by position error, loops (PNG URI)."""
    from matplotlib.collections import LineCollection

    if run.est is None or len(run.est) == 0:
        return None
    est = aligned_positions(run)
    gt_traj = gt_span(run)
    gt = gt_traj.positions if gt_traj is not None else None
    a, b = top_axes(gt_traj.T_world_cam if gt_traj is not None else run.est.T_world_cam)
    fig = new_figure(6.4, 5.2)
    ax = fig.add_subplot(1, 1, 1)
    if gt is not None:
        ax.plot(gt[:, a], gt[:, b], "-", color="0.55", lw=1.5, label="ground truth")
    ev = run.evaluation
    if ev is not None and len(ev.ate_errors) >= 2:
        p = ev.est_aligned.positions
        keep = ~lost_gaps(run, ev.est_aligned.timestamps)  # no segment across frames that were lost
        segs = np.stack([p[:-1][:, [a, b]], p[1:][:, [a, b]]], axis=1)[keep]
        from matplotlib.colors import Normalize

        lc = LineCollection(segs, cmap="viridis", lw=2.0,
                            norm=Normalize(0.0, max(float(ev.ate_errors.max()), 1e-9)))
        lc.set_array((0.5 * (ev.ate_errors[:-1] + ev.ate_errors[1:]))[keep])
        ax.add_collection(lc)
        fig.colorbar(lc, ax=ax, label="position error [m]", shrink=0.8)
        ax.plot([], [], "-", color="#21918c", lw=2, label="estimate (aligned)")
    else:
        line = with_breaks(est[:, [a, b]], lost_gaps(run, run.est.timestamps))  # NaN: lost frames between
        ax.plot(line[:, 0], line[:, 1], "-", color="#3182bd", lw=1.5,
                label="estimate" + (" (aligned)" if ev is not None else ""))
    ax.plot(est[0, a], est[0, b], "o", color="k", ms=5, label="start")
    loops = loop_positions(run, est)
    for i, (q, m, _loop) in enumerate(loops):
        ax.plot([q[a], m[a]], [q[b], m[b]], "--", color="#e31a1c", lw=1.2, label="loop closure" if i == 0 else None)
        ax.plot([q[a], m[a]], [q[b], m[b]], "o", mfc="none", color="#e31a1c", ms=7)
    unit = axis_unit(run, aligned=ev is not None)
    ax.set_xlabel(f"{'xyz'[a]} [{unit}]")
    ax.set_ylabel(f"{'xyz'[b]} [{unit}]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.autoscale_view()
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    ax.set_title("trajectory from above" + (f" ({ev.alignment.mode} aligned)" if ev is not None else ""))
    fig.tight_layout()
    return png_data_uri(fig)


def plot_error(run: RunData) -> str | None:
    """Position error along the ground-truth path (distance travelled) (PNG URI)."""
    ev = run.evaluation
    if ev is None or len(ev.ate_errors) < 2:
        return None
    gt = ev.gt_matched.positions
    dist = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(gt, axis=0), axis=1))])
    fig = new_figure(6.4, 3.0)
    ax = fig.add_subplot(1, 1, 1)
    line = with_breaks(np.column_stack([dist, ev.ate_errors]), lost_gaps(run, ev.gt_matched.timestamps))
    ax.plot(line[:, 0], line[:, 1], "-", color="#08519c", lw=1.2)
    ax.axhline(ev.ate.rmse, color="#e31a1c", lw=1, ls="--", label=f"RMSE {ev.ate.rmse:.4f} m")
    ax.set_ylim(0.0, max(float(ev.ate_errors.max()), 1e-9) * 1.15)
    ax.set_xlabel("distance along the ground-truth path [m]")
    ax.set_ylabel("position error [m]")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title("error along the path")
    fig.tight_layout()
    return png_data_uri(fig)


PER_KEYFRAME_STAGES = ("local_ba",)  # stats.json's stage_ms holds these per call (per keyframe), not per frame
OFF_THREAD_STAGES = ("prepare",)  # another thread's time (frame preparation while prefetching): outside "total"
OTHER_STAGE = "other"  # the tracking time no stage timer covers: ``total`` minus the timed stages


def split_stage_times(stats: dict) -> tuple[dict[str, float], dict[str, float]]:
    """``(per-frame ms, per-keyframe ms)`` of ``stats["stage_ms"]`` (``total`` left out)."""
    stage_ms = {k: float(v) for k, v in (stats.get("stage_ms") or {}).items()
                if isinstance(v, (int, float)) and k != "total"}
    per_kf = {k: v for k, v in stage_ms.items() if k in PER_KEYFRAME_STAGES}
    return {k: v for k, v in stage_ms.items() if k not in per_kf}, per_kf


def stage_bars(stats: dict) -> tuple[dict[str, float], dict[str, float], dict[str, float], float | None]:
    """What the stage chart draws: ``(tracking, off_thread, per_keyframe, tracking_total)``.

    ``tracking`` holds the per-frame stages timed on the tracking thread plus, when ``stage_ms``
    has a ``total`` larger than their sum, an ``other`` stage with the rest, so that
    ``sum(tracking.values()) == tracking_total``: the title's number is the sum of those bars.
    ``tracking_total`` is None when ``stage_ms`` has no ``total``. ``off_thread`` (``prepare``:
    another thread's work) and ``per_keyframe`` (local BA, per call) are not part of it.
    """
    per_frame, per_kf = split_stage_times(stats)
    off_thread = {k: v for k, v in per_frame.items() if k in OFF_THREAD_STAGES and v > 0}
    tracking = {k: v for k, v in per_frame.items() if k not in OFF_THREAD_STAGES}
    total = (stats.get("stage_ms") or {}).get("total")
    if not isinstance(total, (int, float)) or isinstance(total, bool):
        return tracking, off_thread, per_kf, None
    rest = float(total) - sum(tracking.values())
    if rest > 1e-3 * max(float(total), 1.0):  # more than rounding: time no stage timer covers
        tracking[OTHER_STAGE] = tracking.get(OTHER_STAGE, 0.0) + rest
    return tracking, off_thread, per_kf, float(sum(tracking.values()))


def stages_figure(stats: dict):
    """The stage chart as a matplotlib figure (None without stage times); see :func:`plot_stages`."""
    tracking, off_thread, per_kf, total = stage_bars(stats)
    if not tracking and not off_thread and not per_kf:
        return None
    groups = ((tracking, "#6baed6", "{}", "tracking thread, per frame"),
              (off_thread, "#a1d99b", "{} (other thread)", "other thread, per frame"),
              (per_kf, "#fd8d3c", "{} (per keyframe)", "per keyframe"))
    names, values, colors, labels = [], [], [], []
    for stages, color, label, _kind in groups:
        order = sorted((n for n in stages if n != OTHER_STAGE), key=stages.get)
        order += [OTHER_STAGE] if OTHER_STAGE in stages else []  # the rest last, after the timed stages
        for n in order:
            names.append(n)
            values.append(stages[n])
            colors.append(color)
            labels.append(label.format(f"{n} (untimed)" if stages is tracking and n == OTHER_STAGE else n))
    fig = new_figure(6.4, 0.35 * len(names) + 1.3)
    ax = fig.add_subplot(1, 1, 1)
    ax.barh(range(len(names)), values, color=colors)
    ax.set_yticks(range(len(names)), labels, fontsize=8)
    ax.set_xlabel("mean time [ms]")
    from matplotlib.patches import Patch

    ax.legend(handles=[Patch(color=color, label=kind) for stages, color, _l, kind in groups if stages],
              fontsize=7, loc="best")
    ax.set_title("time per stage" + (f": tracking {total:.1f} ms/frame (sum of the blue bars)"
                                     if total is not None else ""), fontsize=10)
    ax.grid(axis="x", alpha=0.3)
    fig.tight_layout()
    return fig


def plot_stages(stats: dict) -> str | None:
    """Mean milliseconds per frame of every tracking stage (and ``other``: the rest of the tracking
    total, so the blue bars add up to the total in the title), of frame preparation on another
    thread, and per keyframe of the mapping stages (local BA), drawn apart (PNG URI)."""
    fig = stages_figure(stats)
    return png_data_uri(fig) if fig is not None else None


def plot_map(run: RunData) -> str | None:
    """The sparse map from above with the (unaligned) estimated trajectory (PNG URI)."""
    if run.points is None or len(run.points[0]) == 0:
        return None
    xyz, rgb = run.points
    traj = run.est.positions if run.est is not None and len(run.est) else None
    a, b = top_axes(run.est.T_world_cam if traj is not None else None, xyz)
    fig = new_figure(6.4, 5.2)
    ax = fig.add_subplot(1, 1, 1)
    colors = rgb / 255.0 if rgb is not None else "#444444"
    ax.scatter(xyz[:, a], xyz[:, b], s=1.0, c=colors, linewidths=0, label=f"{len(xyz)} map points")
    if traj is not None:
        line = with_breaks(traj[:, [a, b]], lost_gaps(run, run.est.timestamps))
        ax.plot(line[:, 0], line[:, 1], "-", color="#e6550d", lw=1.2, label="trajectory")
    unit = axis_unit(run, aligned=False)
    ax.set_xlabel(f"{'xyz'[a]} [{unit}]")
    ax.set_ylabel(f"{'xyz'[b]} [{unit}]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize=8, markerscale=6)
    ax.set_title("sparse map from above (SLAM frame)")
    fig.tight_layout()
    return png_data_uri(fig)
