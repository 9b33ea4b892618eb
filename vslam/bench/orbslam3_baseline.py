"""Optional side-by-side baseline: run ORB-SLAM3 (through the ``pyorbslam3`` wheel) on a sequence.

ORB-SLAM3 is GPL-3.0; ``pyorbslam3`` is never a dependency of vslam and is imported only here,
lazily, when ``vslam bench --baseline orbslam3 --vocabulary ORBvoc.txt`` asks for it. It needs a
DBoW2 *text* vocabulary (none ships with the wheel and its download fails offline).

Known pitfalls (measured, see the project's DEPENDENCIES notes), handled here:

* the settings YAML is written in the older ``Camera.fx`` key form: the v1.0 ``Rectified`` stereo
  form segfaults; the ``Viewer.*`` keys are required even with the viewer off;
* ``save_trajectory_tum`` refuses monocular runs, so the per-frame poses returned by the tracking
  calls are collected instead (``TrackResult.pose_wc``, i.e. ``T_world_cam``, when ``pose_valid``);
* unpaced monocular mapping cannot keep up on 2 cores: frames are paced at the sensor rate.

The result folder follows the ``vslam run`` contract (``trajectory.txt``, ``stats.json``), so the
harness, ``results.md`` and the report treat it like any run.
"""
from __future__ import annotations

import functools
import json
import logging
import time
from pathlib import Path
from typing import Any

import numpy as np

from vslam.errors import VslamError

log = logging.getLogger(__name__)

NAME = "orbslam3"


def _import_pyorbslam3():
    try:
        import pyorbslam3  # noqa: PLC0415 - optional, GPL
    except ImportError:
        raise VslamError(
            "--baseline orbslam3 needs the optional ORB-SLAM3 bindings (GPL-3.0): "
            "pip install pyorbslam3==0.1.1, and pass a DBoW2 text vocabulary with --vocabulary"
        ) from None
    return pyorbslam3


def check_available(vocabulary: str | Path | None) -> Path:
    """Raise :class:`VslamError` unless pyorbslam3 imports and ``vocabulary`` is a readable file."""
    if vocabulary is None:
        raise VslamError("--baseline orbslam3 needs --vocabulary FILE (an ORB-SLAM DBoW2 text vocabulary, "
                         "e.g. ORBvoc.txt); none ships with pyorbslam3")
    vocabulary = Path(vocabulary)
    if not vocabulary.is_file():
        raise VslamError(f"{vocabulary}: ORB-SLAM3 vocabulary not found")
    _import_pyorbslam3()
    return vocabulary.resolve()


def settings_yaml(camera: Any, sensor: str, frame_rate: float, depth_scale: float = 1.0) -> str:
    """ORB-SLAM3 settings in the older ``Camera.*`` form (see the pitfalls above)."""
    dist = np.zeros(5) if camera.dist is None else np.asarray(camera.dist, float).ravel()
    dist = np.pad(dist, (0, max(0, 5 - len(dist))))[:5]
    lines = [
        "%YAML:1.0", "Camera.type: \"PinHole\"",
        f"Camera.fx: {camera.fx}", f"Camera.fy: {camera.fy}", f"Camera.cx: {camera.cx}", f"Camera.cy: {camera.cy}",
        f"Camera.k1: {dist[0]}", f"Camera.k2: {dist[1]}", f"Camera.p1: {dist[2]}", f"Camera.p2: {dist[3]}",
        f"Camera.k3: {dist[4]}",
        f"Camera.width: {camera.width}", f"Camera.height: {camera.height}",
        f"Camera.fps: {max(1, int(round(frame_rate)))}", "Camera.RGB: 0",
        "ORBextractor.nFeatures: 1500", "ORBextractor.scaleFactor: 1.2", "ORBextractor.nLevels: 8",
        "ORBextractor.iniThFAST: 20", "ORBextractor.minThFAST: 7",
        "Viewer.KeyFrameSize: 0.05", "Viewer.KeyFrameLineWidth: 1.0", "Viewer.GraphLineWidth: 0.9",
        "Viewer.PointSize: 2.0", "Viewer.CameraSize: 0.08", "Viewer.CameraLineWidth: 3.0",
        "Viewer.ViewpointX: 0.0", "Viewer.ViewpointY: -0.7", "Viewer.ViewpointZ: -1.8", "Viewer.ViewpointF: 500.0",
    ]
    if sensor in ("stereo", "rgbd"):
        baseline = float(camera.baseline or 0.0)
        lines += [f"Camera.bf: {camera.fx * baseline if sensor == 'stereo' else camera.fx * 0.08}",
                  f"ThDepth: {40.0 if sensor == 'stereo' else 40.0}"]
    if sensor == "rgbd":
        lines.append(f"DepthMapFactor: {depth_scale}")  # frames carry depth in metres already
    return "\n".join(lines) + "\n"


def _track(slam: Any, sensor: str, frame: Any) -> np.ndarray | None:
    """One tracking call of ``pyorbslam3.Slam``; ``T_world_cam`` (its ``pose_wc``) or None.

    ``pose_valid`` is true for ORB-SLAM3's OK and RECENTLY_LOST states; otherwise ORB-SLAM3
    reports an identity pose, which is dropped.
    """
    if sensor == "rgbd":
        res = slam.track_rgbd(frame.image, frame.depth.astype(np.float32), frame.timestamp)
    elif sensor == "stereo":
        res = slam.track_stereo(frame.image, frame.image_right, frame.timestamp)
    else:
        res = slam.track_monocular(frame.image, frame.timestamp)
    if not getattr(res, "pose_valid", False) or getattr(res, "pose_wc", None) is None:
        return None
    T = np.asarray(res.pose_wc, dtype=float)
    return T if T.shape == (4, 4) and np.all(np.isfinite(T)) else None


def run_orbslam3(path: str | Path, output: str | Path | None, sensor: str | None = None, dataset: str | None = None,
                 config: Any = None, overrides=(), max_frames: int | None = None, start_frame: int = 0,
                 progress: bool = False, vocabulary: str | Path | None = None, pace: bool = True) -> dict:
    """Run ORB-SLAM3 over a sequence, a runner for :func:`vslam.bench.harness.run_benchmark`.

    Same signature as :func:`vslam.api.run_path` plus ``vocabulary``; ``config``/``overrides``
    (vslam settings) are ignored. Writes ``trajectory.txt`` and ``stats.json`` with ATE/RPE.
    """
    from vslam.api import choose_sensor
    from vslam.datasets import open_dataset
    from vslam.eval.trajectory import Trajectory, write_tum
    from vslam.runner import _evaluate

    vocabulary = check_available(vocabulary)
    orb = _import_pyorbslam3()
    probe = open_dataset(path, kind=dataset)
    sensor = choose_sensor(probe.sensors, sensor)
    ds = open_dataset(path, kind=dataset, sensor=sensor)
    out = Path(output) if output is not None else Path(".")
    out.mkdir(parents=True, exist_ok=True)
    settings = out / "orbslam3_settings.yaml"
    settings.write_text(settings_yaml(ds.camera, sensor, ds.frame_rate))
    kind = {"mono": orb.Sensor.MONOCULAR, "stereo": orb.Sensor.STEREO, "rgbd": orb.Sensor.RGBD}[sensor]
    slam = orb.Slam(str(vocabulary), str(settings), kind, use_viewer=False)
    stop = len(ds) if max_frames is None else min(len(ds), start_frame + max_frames)
    ts, poses = [], []
    n = 0
    t0 = time.perf_counter()
    period = 1.0 / ds.frame_rate if pace and ds.frame_rate else 0.0
    try:
        for frame in ds.frames(start_frame, stop):
            t_frame = time.perf_counter()
            T_world_cam = _track(slam, sensor, frame)
            n += 1
            if T_world_cam is not None:
                ts.append(frame.timestamp)
                poses.append(T_world_cam)
            if period:
                time.sleep(max(0.0, period - (time.perf_counter() - t_frame)))
    finally:
        slam.shutdown()
    wall = time.perf_counter() - t0
    traj = Trajectory(np.asarray(ts, float), np.asarray(poses, float).reshape(-1, 4, 4))
    stats = {"frames": n, "tracked": len(ts), "lost": n - len(ts), "wall_s": round(wall, 3),
             "fps": round(n / wall, 2) if wall > 0 else 0.0, "loops": [], "sensor": sensor, "dataset": ds.kind,
             "path": str(path), "start_frame": start_frame, "system": NAME, "paced": bool(period)}
    gt = ds.ground_truth()
    if gt is not None and len(traj) >= 3:
        stats.update(_evaluate(traj, gt, "sim3" if sensor == "mono" else "se3"))
    if output is not None:
        write_tum(out / "trajectory.txt", traj)
        (out / "stats.json").write_text(json.dumps(stats, indent=2))
    return stats


def make_runner(vocabulary: str | Path | None):
    """A picklable runner bound to ``vocabulary`` (checked now, so a bad setup fails before any run)."""
    vocabulary = check_available(vocabulary)
    return functools.partial(run_orbslam3, vocabulary=str(vocabulary))
