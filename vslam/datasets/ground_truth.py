"""Which ground truth a run is evaluated against, named, and never fatal.

:func:`resolve_ground_truth` picks the ground truth of a run: the dataset's own (TUM
``groundtruth.txt``, KITTI ``poses/NN.txt``, EuRoC cam0, 7-Scenes ``*.pose.txt``, a
``groundtruth.txt`` beside a ROS bag), a file the user chose (``--gt FILE``), or none (``--gt
none``). It returns a :class:`GroundTruth` that names the file and the frame its poses are of
(``gt_file``, ``gt_frame`` in ``stats.json``).

Ground truth is optional to SLAM, so a problem with the dataset's own never stops a run: repeated
timestamps keep the last pose (with a warning, as ``vslam eval`` and evo do), and anything else
(unreadable, malformed, no pose at any frame time) skips the evaluation with a warning that
names the file and the problem. A file chosen with ``--gt`` that does not exist is a typo on the
command line and raises :class:`~vslam.errors.DatasetError` before anything runs.

Example::

    gt = resolve_ground_truth(open_dataset("data/fr1_desk"))
    gt.trajectory, gt.file, gt.frame      # Trajectory | None, ".../groundtruth.txt", "rgb"
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from vslam.datasets.timestamps import interpolate_poses
from vslam.errors import DatasetError
from vslam.trajectory import Trajectory

log = logging.getLogger(__name__)

#: the camera whose pose each reader's ground truth gives, by dataset kind (``gt_frame``)
GT_FRAMES = {"tum": "rgb", "kitti": "cam0", "euroc": "cam0"}
#: ``gt_frame`` of a file chosen with ``--gt``: its poses are taken as they are
GIVEN_FRAME = "as given"
#: a ``--gt FILE`` pose is used for a frame within this many seconds of it (interpolated)
GIVEN_MAX_GAP = 0.1


@dataclass(frozen=True)
class GroundTruth:
    """The ground truth of a run: ``trajectory`` at the frame timestamps (None: no evaluation),
    the ``file`` it came from, the ``frame`` its poses are of, and ``problem``: why a ground
    truth that exists is not used (already warned about), else None."""

    trajectory: Trajectory | None = None
    file: str | None = None
    frame: str | None = None
    problem: str | None = None

    def stats(self) -> dict:
        """The ``stats.json`` keys: ``gt_file`` (None without ground truth), ``gt_frame`` when it
        is used, ``gt_problem`` when one was found but not used."""
        out: dict[str, Any] = {"gt_file": self.file if self.trajectory is not None else None}
        if self.trajectory is not None:
            out["gt_frame"] = self.frame
        if self.problem is not None:
            out["gt_problem"] = f"{self.file}: {self.problem}"
        return out


def is_none_choice(choice: Any) -> bool:
    """``--gt none``."""
    return isinstance(choice, str) and choice.strip().lower() == "none"


def resolve_ground_truth(ds: Any, choice: str | Path | None = None,
                         frames: tuple[int, int] | None = None) -> GroundTruth:
    """The ground truth of a run over dataset ``ds``: ``choice`` None uses the dataset's own,
    ``"none"`` none, anything else is a trajectory file (TUM, KITTI or EuRoC, detected).
    ``frames`` ``(start, stop)``: the frames the run uses; a ground truth with a pose at none of
    them is not used (with a warning).

    Raises :class:`DatasetError` only when a chosen file does not exist.
    """
    if is_none_choice(choice):
        log.info("ground truth: none (--gt none)")
        return GroundTruth()
    truth = _chosen_file(ds, Path(choice).resolve()) if choice is not None else _dataset_own(ds)
    if truth.trajectory is None or frames is None:
        return truth
    return _within(truth, ds, frames)


def _within(truth: GroundTruth, ds: Any, frames: tuple[int, int]) -> GroundTruth:
    """``truth``, or none (warned) when it has no pose at the frames ``start .. stop - 1``."""
    start, stop = frames
    times = np.asarray(getattr(ds, "timestamps", np.zeros(0)), dtype=float)[start:stop]
    t = truth.trajectory.timestamps
    if len(times) and not np.any((t >= times[0] - 1e-6) & (t <= times[-1] + 1e-6)):
        problem = (f"no pose at any frame of this run (frames {start}..{stop - 1}, {times[0]:.3f}..{times[-1]:.3f} s;"
                   f" it covers {t[0]:.3f}..{t[-1]:.3f} s)")
        return _skipped(truth.file or "", problem, truth.frame or "")
    return truth


def dataset_gt_file(ds: Any) -> Path | None:
    """The file holding the dataset's own ground truth, or None when it has none (or the reader
    does not say)."""
    fn = getattr(ds, "ground_truth_file", None)
    path = fn() if callable(fn) else None
    if path is None and getattr(ds, "kind", "") == "euroc":
        path = _euroc_gt_file(ds)
    if path is None and getattr(ds, "kind", "") == "7scenes" and any(Path(ds.root).glob("frame-*.pose.txt")):
        path = Path(ds.root) / "frame-*.pose.txt"  # one pose file per frame
    return Path(path).resolve() if path is not None else None


def _euroc_gt_file(ds: Any) -> Path | None:
    """The file the EuRoC reader takes its ground truth from (its own search order)."""
    root, mav0 = getattr(ds, "root", None), getattr(ds, "mav0", None)
    if root is None:
        return None
    cands = [Path(root) / "groundtruth_cam0_tum.txt"]
    if mav0 is not None:
        cands.append(Path(mav0) / "state_groundtruth_estimate0" / "data.csv")
    cands += sorted(Path(root).glob("*_GT_left_cam.txt")) + sorted(Path(root).glob("*_GT.txt"))
    return next((c for c in cands if c.is_file()), None)


def _dataset_own(ds: Any) -> GroundTruth:
    """The dataset's own ground truth; a problem with it is a warning, never an error."""
    file = dataset_gt_file(ds)
    name = str(file) if file is not None else f"the ground truth of {getattr(ds, 'root', 'the dataset')}"
    frame = GT_FRAMES.get(getattr(ds, "kind", ""), "camera")
    try:
        traj = ds.ground_truth()
    except Exception as exc:  # noqa: BLE001 - ground truth is optional: never stop a run over it
        log.debug("reading the ground truth failed", exc_info=True)
        return _skipped(name, _problem_text(exc, name), frame)
    if traj is None:
        if file is None:
            return GroundTruth()
        return _skipped(name, f"no pose at any frame time ({_spans(ds, file)})", frame)
    return GroundTruth(traj, str(file) if file is not None else name, frame)


def _chosen_file(ds: Any, path: Path) -> GroundTruth:
    """A trajectory file chosen with ``--gt``, at the frame timestamps; KITTI rows are frames."""
    from vslam.trajectory import detect_format, read_trajectory

    if not path.is_file():
        raise DatasetError(f"--gt {path}: no such file; name a TUM, KITTI or EuRoC trajectory, or --gt none")
    try:
        fmt = detect_format(path)
        gt = read_trajectory(path, fmt, duplicates="keep_last")
    except Exception as exc:  # noqa: BLE001 - ground truth is optional: never stop a run over it
        log.debug("reading --gt failed", exc_info=True)
        return _skipped(str(path), _problem_text(exc, str(path)), GIVEN_FRAME)
    gt, frame, problem = _body_to_camera(ds, path, gt) if fmt == "euroc" else (gt, GIVEN_FRAME, None)
    if problem is not None:
        return _skipped(str(path), problem, GIVEN_FRAME)
    times = np.asarray(getattr(ds, "timestamps", np.zeros(0)), dtype=float)
    if fmt == "kitti":  # one pose per image, no times of its own
        n = min(len(gt), len(times))
        T, valid = gt.T_world_cam[:n], np.ones(n, dtype=bool)
        times = times[:n]
    else:
        T, valid = interpolate_poses(gt, times, max_gap=GIVEN_MAX_GAP)
    if not np.any(valid):
        return _skipped(str(path), f"no pose at any frame time ({_spans(ds, path, gt)})", frame)
    return GroundTruth(Trajectory(times[valid], T[valid]), str(path), frame)


def _body_to_camera(ds: Any, path: Path, gt: Trajectory) -> tuple[Trajectory, str, str | None]:
    """``(ground truth, gt_frame, problem)``: EuRoC body-frame ground truth
    (:func:`vslam.datasets.gt_frames.body_frame_reference`) converted to cam0 (and to the rectified
    left camera of a EuRoC stereo run), said in the log; other files as given."""
    from vslam.datasets.gt_frames import body_frame_reference
    from vslam.errors import TrajectoryError

    try:
        conv = body_frame_reference(path, option=None)
    except TrajectoryError as exc:
        return gt, GIVEN_FRAME, _problem_text(exc, str(path))
    if conv is None:
        return gt, GIVEN_FRAME, None
    log.warning("ground truth %s", conv.line().removeprefix("reference "))
    T_right = conv.T_body_cam @ np.asarray(getattr(ds, "T_cam0_rect", np.eye(4)), dtype=float)
    return Trajectory(gt.timestamps, gt.T_world_cam @ T_right), "cam0 (converted from the body frame)", None


def _skipped(name: str, problem: str, frame: str) -> GroundTruth:
    log.warning("ground truth %s not used, the evaluation is skipped: %s (fix it, choose another with --gt FILE, "
                "or --gt none)", name, problem)
    return GroundTruth(None, name, frame, problem)


def _problem_text(exc: BaseException, name: str) -> str:
    """The exception as one line, without the file name the warning already gives."""
    text = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
    if text.startswith(f"{name}:"):
        text = text[len(name) + 1:].lstrip()
        line, sep, rest = text.partition(": ")
        if sep and line.isdigit():  # "12: not a number ..." (the file's line 12)
            text = f"line {line}: {rest}"
    return text


def _spans(ds: Any, file: Path, gt: Trajectory | None = None) -> str:
    """``frames t0..t1 s, ground truth g0..g1 s`` (what is known of the two time spans)."""
    times = np.asarray(getattr(ds, "timestamps", np.zeros(0)), dtype=float)
    parts = [f"frames {times[0]:.3f}..{times[-1]:.3f} s"] if len(times) else []
    if gt is None:
        try:
            from vslam.trajectory import read_trajectory

            gt = read_trajectory(file, duplicates="keep_last")
        except Exception:  # noqa: BLE001 - only for the message
            gt = None
    if gt is not None and len(gt):
        parts.append(f"ground truth {gt.timestamps[0]:.3f}..{gt.timestamps[-1]:.3f} s")
    return ", ".join(parts) or "no overlap"
