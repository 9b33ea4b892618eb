"""Optional side-by-side baseline: run ORB-SLAM3 (the ``pyorbslam3`` wheel) on a sequence.

ORB-SLAM3 is GPL-3.0 and ``pyorbslam3`` must never be installed beside vslam (see the project's
DEPENDENCIES notes), so the baseline runs in a **subprocess** with another Python interpreter:

* the interpreter is ``--baseline-python PY`` (``vslam bench``), else ``$VSLAM_ORBSLAM3_PYTHON``,
  else the current one when it can import ``pyorbslam3``;
* that interpreter needs ``pyorbslam3`` and what ``vslam.datasets`` imports (numpy, scipy,
  opencv-contrib-python-headless, pyyaml); vslam itself is put on its ``PYTHONPATH`` by the parent,
  so both systems read exactly the same frames (same loaders, same EuRoC rectification);
* it needs a DBoW2 *text* vocabulary (``--vocabulary``, else ``$PYORBSLAM3_VOCAB``): none ships
  with the wheel and its download fails offline. ``vslam vocab train ... --output ORBvoc.txt``
  writes one (a k=10, L=5 tree on the ~1300 frames of the shared sequences works).

Protocol: the parent runs ``PY -m vslam.bench.orbslam3_baseline --data PATH --output DIR
--vocabulary FILE [--sensor S] [--dataset KIND] [--start-frame N] [--max-frames N] [--pace P]
[--pace-rate R]``;
the child writes ``DIR/trajectory.txt`` (TUM, ``T_world_cam``) and ``DIR/orbslam3_stats.json``
(frames, tracked, timing), its log in ``DIR/orbslam3.log``. The parent evaluates ATE/RPE against
the ground truth as for a vslam run and writes ``DIR/stats.json``, so the harness, ``results.md``
and the report treat it like any run.

Pitfalls of the wheel (measured), handled here:

* the settings YAML uses the older ``Camera.fx`` key form: the v1.0 ``Rectified`` stereo form
  segfaults; the ``Viewer.*`` keys are required even with the viewer off;
* ``save_trajectory_tum`` refuses monocular runs: the final trajectory is saved in EuRoC format
  (nanosecond timestamps) and converted; the per-frame online poses (``TrackResult.pose_wc``) are
  the fallback when that file is empty;
* unpaced monocular mapping cannot keep up on 2 cores: by default (``pace="mono"``) monocular runs
  are fed at the sensor rate times ``pace_rate`` (default 1), which caps their frames/s at that
  rate (``stats["paced"]``). On a loaded machine even the sensor rate is too fast (measured: KITTI
  07 at load ~8 resets its map twice at 10 Hz, tracks 156/160 frames at 4 Hz): lower ``pace_rate``.
"""
from __future__ import annotations

import argparse
import functools
import importlib.util
import json
import logging
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from vslam.errors import VslamError

log = logging.getLogger(__name__)

NAME = "orbslam3"
#: environment variable naming the Python interpreter that has pyorbslam3
PYTHON_ENV = "VSLAM_ORBSLAM3_PYTHON"
#: environment variable naming the DBoW2 text vocabulary (pyorbslam3's own convention)
VOCAB_ENV = "PYORBSLAM3_VOCAB"
#: which sensors are fed at the sensor rate: ``mono`` (default), ``all`` or ``none``
PACE_CHOICES = ("mono", "all", "none")
#: what the child interpreter must be able to import
_CHILD_IMPORTS = "import pyorbslam3, numpy, scipy, cv2, yaml, vslam.datasets"

SETUP_HELP = (
    "make a separate virtual environment for it (never install pyorbslam3 into vslam's own: it is "
    "GPL-3.0 and may replace cv2): python3.11 -m venv orbvenv && orbvenv/bin/pip install "
    "pyorbslam3==0.1.1 numpy==2.4.6 scipy==1.17.1 opencv-contrib-python-headless==4.14.0.94 pyyaml==6.0.3 numba==0.68.1; "
    f"then pass --baseline-python orbvenv/bin/python (or set {PYTHON_ENV})"
)


# ----------------------------------------------------------------------------------------------
# parent side: find the interpreter, run the child, evaluate
# ----------------------------------------------------------------------------------------------
@functools.lru_cache(maxsize=1)
def _vslam_root() -> Path:
    """A folder that holds this ``vslam`` package and nothing else of this environment, for the
    child's ``PYTHONPATH``: the source checkout, or, for an installed vslam, a temporary folder with
    a link to it (putting site-packages on the path would bring this env's cv2/numpy along)."""
    import atexit
    import shutil
    import tempfile

    package = Path(__file__).resolve().parents[1]
    if package.parent.name not in ("site-packages", "dist-packages"):
        return package.parent
    tmp = Path(tempfile.mkdtemp(prefix="vslam-orbslam3-path-"))
    (tmp / "vslam").symlink_to(package, target_is_directory=True)
    atexit.register(shutil.rmtree, tmp, True)
    return tmp


def child_env() -> dict[str, str]:
    """The child's environment: this one, with vslam's folder first on ``PYTHONPATH``."""
    env = dict(os.environ)
    paths = [str(_vslam_root())] + [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p]
    env["PYTHONPATH"] = os.pathsep.join(dict.fromkeys(paths))
    return env


def resolve_python(python: str | Path | None = None) -> str:
    """The interpreter that runs ORB-SLAM3: ``python``, else ``$VSLAM_ORBSLAM3_PYTHON``, else this
    one when it can import ``pyorbslam3``; raises :class:`VslamError` with setup steps otherwise."""
    python = python or os.environ.get(PYTHON_ENV) or None
    if python is None:
        if importlib.util.find_spec("pyorbslam3") is not None:
            return sys.executable
        raise VslamError(f"--baseline orbslam3 needs a Python interpreter with the ORB-SLAM3 bindings "
                         f"(pyorbslam3, GPL-3.0): {SETUP_HELP}")
    path = Path(python).expanduser()
    if not path.is_file() or not os.access(path, os.X_OK):
        raise VslamError(f"{python}: not an executable Python interpreter (--baseline-python / {PYTHON_ENV}); "
                         f"{SETUP_HELP}")
    return str(path)


def check_python(python: str) -> None:
    """Raise :class:`VslamError` unless ``python`` imports pyorbslam3 and vslam's dataset loaders."""
    try:
        proc = subprocess.run([python, "-c", _CHILD_IMPORTS], env=child_env(), capture_output=True,
                              text=True, timeout=120)
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise VslamError(f"{python}: cannot run it ({exc}); {SETUP_HELP}") from None
    if proc.returncode != 0:
        last = (proc.stderr.strip().splitlines() or ["(no output)"])[-1]
        raise VslamError(f"{python} cannot run the ORB-SLAM3 baseline ({last}); {SETUP_HELP}")


def check_vocabulary(vocabulary: str | Path | None) -> Path:
    """The vocabulary file (``vocabulary``, else ``$PYORBSLAM3_VOCAB``), resolved; or raise."""
    vocabulary = vocabulary or os.environ.get(VOCAB_ENV) or None
    if vocabulary is None:
        raise VslamError("--baseline orbslam3 needs --vocabulary FILE (an ORB-SLAM DBoW2 text vocabulary, "
                         "e.g. ORBvoc.txt); none ships with pyorbslam3. Write one with "
                         "`vslam vocab train SEQUENCE... --output ORBvoc.txt` (k=10, L=5) or "
                         "`vslam vocab convert vslam/data/orb_vocabulary_k10_L4.npz ORBvoc.txt`")
    vocabulary = Path(vocabulary).expanduser()
    if not vocabulary.is_file():
        raise VslamError(f"{vocabulary}: ORB-SLAM3 vocabulary not found")
    return vocabulary.resolve()


def check_available(vocabulary: str | Path | None, python: str | Path | None = None) -> tuple[Path, str]:
    """Check the vocabulary and the baseline interpreter; returns ``(vocabulary, python)``."""
    vocabulary = check_vocabulary(vocabulary)
    python = resolve_python(python)
    check_python(python)
    return vocabulary, python


def child_command(python: str, path: str | Path, output: str | Path, vocabulary: str | Path,
                  sensor: str | None = None, dataset: str | None = None, max_frames: int | None = None,
                  start_frame: int = 0, pace: str = "mono", pace_rate: float = 1.0) -> list[str]:
    """The command line of one baseline run (see the module docstring)."""
    cmd = [python, "-m", "vslam.bench.orbslam3_baseline", "--data", str(path), "--output", str(output),
           "--vocabulary", str(vocabulary), "--start-frame", str(start_frame), "--pace", pace,
           "--pace-rate", repr(float(pace_rate))]
    if sensor:
        cmd += ["--sensor", sensor]
    if dataset:
        cmd += ["--dataset", dataset]
    if max_frames is not None:
        cmd += ["--max-frames", str(max_frames)]
    return cmd


def _describe_exit(code: int) -> str:
    if code < 0:
        try:
            return f"was killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"was killed by signal {-code}"
    return f"exited with status {code}"


def _log_tail(log_path: Path, n: int = 3) -> str:
    try:
        lines = [ln.strip() for ln in log_path.read_text(errors="replace").splitlines() if ln.strip()]
    except OSError:
        return ""
    return " | ".join(lines[-n:])


def run_orbslam3(path: str | Path, output: str | Path | None, sensor: str | None = None, dataset: str | None = None,
                 config: Any = None, overrides: Sequence[str] = (), max_frames: int | None = None,
                 start_frame: int = 0, progress: bool = False, vocabulary: str | Path | None = None,
                 python: str | Path | None = None, pace: str = "mono", pace_rate: float = 1.0,
                 timeout: float | None = None) -> dict:
    """Run ORB-SLAM3 over a sequence in the baseline interpreter; a runner for
    :func:`vslam.bench.harness.run_benchmark`.

    Same signature as :func:`vslam.api.run_path` plus ``vocabulary``, ``python``, ``pace``,
    ``pace_rate`` and ``timeout`` (seconds); ``config``/``overrides`` (vslam settings) are ignored. Writes
    ``trajectory.txt`` and ``stats.json`` (with ATE/RPE when the sequence has ground truth) into
    ``output`` and returns the stats.

    Raises:
        VslamError: the setup is missing, or the child failed (its exit status or signal and the
            end of ``orbslam3.log`` are in the message).
    """
    from vslam.datasets import open_dataset
    from vslam.trajectory import read_trajectory
    from vslam.runner import trajectory_errors

    _check_pace(pace, pace_rate)
    vocabulary = check_vocabulary(vocabulary)
    python = resolve_python(python)
    out = Path(output) if output is not None else Path(".")
    out.mkdir(parents=True, exist_ok=True)
    log_path = out / "orbslam3.log"
    cmd = child_command(python, path, out, vocabulary, sensor, dataset, max_frames, start_frame, pace, pace_rate)
    log.info("ORB-SLAM3 baseline: %s", " ".join(cmd))
    t0 = time.perf_counter()
    with open(log_path, "w") as log_file:
        try:
            proc = subprocess.run(cmd, env=child_env(), stdout=log_file, stderr=subprocess.STDOUT, timeout=timeout)
        except subprocess.TimeoutExpired:
            raise VslamError(f"the ORB-SLAM3 baseline ran past {timeout} s; see {log_path}") from None
    elapsed = time.perf_counter() - t0
    child_stats_path = out / "orbslam3_stats.json"
    try:
        stats = json.loads(child_stats_path.read_text())
    except (OSError, ValueError):
        stats = {}
    if proc.returncode != 0 or not stats:
        raise VslamError(f"the ORB-SLAM3 baseline {_describe_exit(proc.returncode)} "
                         f"({_log_tail(log_path) or 'no output'}); see {log_path}")
    stats["process_wall_s"] = round(elapsed, 3)
    traj_path = out / "trajectory.txt"
    traj = read_trajectory(traj_path) if traj_path.is_file() and traj_path.stat().st_size else None
    ds = open_dataset(path, kind=dataset, sensor=stats.get("sensor", sensor))
    gt = ds.ground_truth()
    if gt is not None and traj is not None and len(traj) >= 3:
        stats.update(trajectory_errors(traj, gt, "sim3" if stats.get("sensor") == "mono" else "se3"))
    (out / "stats.json").write_text(json.dumps(stats, indent=2))
    return stats


def _check_pace(pace: str, pace_rate: float) -> None:
    if pace not in PACE_CHOICES:
        raise VslamError(f"--baseline-pace must be one of {', '.join(PACE_CHOICES)}, got {pace!r}")
    if not pace_rate > 0:
        raise VslamError(f"--baseline-pace-rate must be > 0 (a factor of the sensor rate), got {pace_rate}")


def make_runner(vocabulary: str | Path | None, python: str | Path | None = None, pace: str = "mono",
                pace_rate: float = 1.0, timeout: float | None = None):
    """A picklable runner bound to the vocabulary and interpreter (both checked now, so a bad setup
    fails before any run)."""
    _check_pace(pace, pace_rate)
    vocabulary, python = check_available(vocabulary, python)
    return functools.partial(run_orbslam3, vocabulary=str(vocabulary), python=python, pace=pace,
                             pace_rate=pace_rate, timeout=timeout)


# ----------------------------------------------------------------------------------------------
# child side: runs in the interpreter that has pyorbslam3
# ----------------------------------------------------------------------------------------------
def _import_pyorbslam3():
    try:
        import pyorbslam3  # noqa: PLC0415 - optional, GPL, only in the baseline interpreter
    except ImportError:
        raise VslamError(f"{sys.executable} cannot import pyorbslam3; {SETUP_HELP}") from None
    return pyorbslam3


def settings_yaml(camera: Any, sensor: str, frame_rate: float, depth_scale: float = 1.0) -> str:
    """ORB-SLAM3 settings in the older ``Camera.*`` form (see the pitfalls above).

    ORB parameters follow ORB-SLAM3's example settings: 2000 features for KITTI-sized images
    (> 400k pixels), 1000 for 640x480; stereo/RGB-D ``ThDepth`` 40 baselines (KITTI uses 35).
    """
    dist = np.zeros(5) if camera.dist is None else np.asarray(camera.dist, float).ravel()
    dist = np.pad(dist, (0, max(0, 5 - len(dist))))[:5]
    n_features = 2000 if camera.width * camera.height > 400_000 else 1000
    lines = [
        "%YAML:1.0", "Camera.type: \"PinHole\"",
        f"Camera.fx: {camera.fx}", f"Camera.fy: {camera.fy}", f"Camera.cx: {camera.cx}", f"Camera.cy: {camera.cy}",
        f"Camera.k1: {dist[0]}", f"Camera.k2: {dist[1]}", f"Camera.p1: {dist[2]}", f"Camera.p2: {dist[3]}",
        f"Camera.k3: {dist[4]}",
        f"Camera.width: {camera.width}", f"Camera.height: {camera.height}",
        f"Camera.fps: {max(1, int(round(frame_rate)))}", "Camera.RGB: 0",
        f"ORBextractor.nFeatures: {n_features}", "ORBextractor.scaleFactor: 1.2", "ORBextractor.nLevels: 8",
        "ORBextractor.iniThFAST: 20", "ORBextractor.minThFAST: 7",
        "Viewer.KeyFrameSize: 0.05", "Viewer.KeyFrameLineWidth: 1.0", "Viewer.GraphLineWidth: 0.9",
        "Viewer.PointSize: 2.0", "Viewer.CameraSize: 0.08", "Viewer.CameraLineWidth: 3.0",
        "Viewer.ViewpointX: 0.0", "Viewer.ViewpointY: -0.7", "Viewer.ViewpointZ: -1.8", "Viewer.ViewpointF: 500.0",
    ]
    if sensor in ("stereo", "rgbd"):
        baseline = float(camera.baseline or 0.0)
        lines += [f"Camera.bf: {camera.fx * baseline if sensor == 'stereo' else camera.fx * 0.08}",
                  "ThDepth: 40.0"]
    if sensor == "rgbd":
        lines.append(f"DepthMapFactor: {depth_scale}")  # frames carry depth in metres already
    return "\n".join(lines) + "\n"


def _track(slam: Any, sensor: str, frame: Any) -> np.ndarray | None:
    """One tracking call of ``pyorbslam3.Slam``; ``T_world_cam`` (its ``pose_wc``) or None.

    ``pose_valid`` is true for ORB-SLAM3's OK and RECENTLY_LOST states; otherwise ORB-SLAM3
    reports no pose, and the frame counts as lost.
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


def read_euroc_ns(path: str | Path):
    """ORB-SLAM3's ``SaveTrajectoryEuRoC`` file (``t_ns tx ty tz qx qy qz qw``, spaces) as a
    :class:`~vslam.trajectory.Trajectory` in seconds; None when missing or empty.

    ORB-SLAM3 repeats the last frame's time and pose for every frame it lost: only the first line
    of each timestamp is kept, so lost frames do not count as poses.
    """
    from scipy.spatial.transform import Rotation

    from vslam.trajectory import Trajectory

    path = Path(path)
    if not path.is_file() or path.stat().st_size == 0:
        return None
    data = np.loadtxt(path, ndmin=2)
    if data.shape[0] == 0 or data.shape[1] != 8:
        return None
    _, first = np.unique(data[:, 0], return_index=True)  # sorted by time, first of equal times
    data = data[first]
    T = np.tile(np.eye(4), (len(data), 1, 1))
    T[:, :3, :3] = Rotation.from_quat(data[:, 4:8]).as_matrix()
    T[:, :3, 3] = data[:, 1:4]
    return Trajectory(data[:, 0] * 1e-9, T)


def track_sequence(path: str | Path, output: str | Path, vocabulary: str | Path, sensor: str | None = None,
                   dataset: str | None = None, max_frames: int | None = None, start_frame: int = 0,
                   pace: str = "mono", pace_rate: float = 1.0) -> dict:
    """The child's work: feed the sequence to ORB-SLAM3, write ``trajectory.txt`` and
    ``orbslam3_stats.json`` into ``output``; returns the stats (no evaluation here).

    ``fps`` is frames / ``wall_s``, where ``wall_s`` covers reading the frames, tracking and
    ``shutdown()`` (ORB-SLAM3 finishing local mapping and loop closing), as for a vslam run;
    loading the vocabulary is ``init_s``. ``track_ms_*`` is the time spent in the tracking calls.
    """
    from vslam.datasets import open_dataset
    from vslam.trajectory import Trajectory, write_tum

    orb = _import_pyorbslam3()
    out = Path(output)
    out.mkdir(parents=True, exist_ok=True)
    probe = open_dataset(path, kind=dataset)
    if sensor is None:
        sensor = next((s for s in ("rgbd", "stereo", "mono") if s in probe.sensors), None)
    if sensor not in probe.sensors:
        raise VslamError(f"{path} provides {', '.join(probe.sensors)}; it cannot be run as {sensor!r}")
    ds = open_dataset(path, kind=dataset, sensor=sensor)
    settings = out / "orbslam3_settings.yaml"
    settings.write_text(settings_yaml(ds.camera, sensor, ds.frame_rate))
    kind = {"mono": orb.Sensor.MONOCULAR, "stereo": orb.Sensor.STEREO, "rgbd": orb.Sensor.RGBD}[sensor]
    t_init = time.perf_counter()
    slam = orb.Slam(str(vocabulary), str(settings), kind, use_viewer=False)
    init_s = time.perf_counter() - t_init
    stop = len(ds) if max_frames is None else min(len(ds), start_frame + max_frames)
    paced = pace == "all" or (pace == "mono" and sensor == "mono")
    period = 1.0 / (ds.frame_rate * pace_rate) if paced and ds.frame_rate else 0.0
    ts, poses, track_ms = [], [], []
    n = 0
    t0 = time.perf_counter()
    try:
        for frame in ds.frames(start_frame, stop):
            t_frame = time.perf_counter()
            T_world_cam = _track(slam, sensor, frame)
            track_ms.append(1e3 * (time.perf_counter() - t_frame))
            n += 1
            if T_world_cam is not None:
                ts.append(frame.timestamp)
                poses.append(T_world_cam)
            if n % 100 == 0:
                log.info("frame %d: %d tracked", n, len(ts))
            if period:
                time.sleep(max(0.0, period - (time.perf_counter() - t_frame)))
    finally:
        t_shutdown = time.perf_counter()
        slam.shutdown()
        shutdown_s = time.perf_counter() - t_shutdown
    wall = time.perf_counter() - t0
    online = Trajectory(np.asarray(ts, float), np.asarray(poses, float).reshape(-1, 4, 4))
    write_tum(out / "trajectory_online.txt", online)
    euroc_path = out / "orbslam3_trajectory_euroc.txt"
    final = None
    try:
        slam.save_trajectory_euroc(str(euroc_path))  # the final (loop-corrected) poses, mono included
        final = read_euroc_ns(euroc_path)
    except Exception as exc:  # keep the online poses
        log.warning("save_trajectory_euroc failed: %s", exc)
    traj, source = (final, "final") if final is not None and len(final) else (online, "online")
    write_tum(out / "trajectory.txt", traj)
    track = np.asarray(track_ms) if track_ms else np.zeros(1)
    # tracked = poses in the evaluated trajectory: ORB-SLAM3's saved trajectory drops frames of
    # maps it reset or did not keep; tracked_online counts the frames its tracking gave a pose
    stats = {"frames": n, "tracked": len(traj), "lost": n - len(traj), "tracked_online": len(ts),
             "wall_s": round(wall, 3),
             "fps": round(n / wall, 2) if wall > 0 else 0.0, "init_s": round(init_s, 3),
             "shutdown_s": round(shutdown_s, 3), "track_ms_mean": round(float(track.mean()), 2),
             "track_ms_median": round(float(np.median(track)), 2), "loops": [], "sensor": sensor,
             "dataset": ds.kind, "path": str(path), "start_frame": start_frame, "system": NAME,
             "paced": paced, "pace_rate": pace_rate if paced else None, "frame_rate": round(float(ds.frame_rate), 4) if ds.frame_rate else None,
             "trajectory": source, "vocabulary": str(vocabulary)}
    (out / "orbslam3_stats.json").write_text(json.dumps(stats, indent=2))
    return stats


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the child process (``python -m vslam.bench.orbslam3_baseline``)."""
    p = argparse.ArgumentParser(prog="python -m vslam.bench.orbslam3_baseline",
                                description="Run ORB-SLAM3 (pyorbslam3) on a sequence; the side of "
                                            "`vslam bench --baseline orbslam3` that needs the GPL wheel.")
    p.add_argument("--data", required=True)
    p.add_argument("--output", required=True)
    p.add_argument("--vocabulary", required=True)
    p.add_argument("--sensor", choices=["mono", "stereo", "rgbd"])
    p.add_argument("--dataset")
    p.add_argument("--start-frame", type=int, default=0)
    p.add_argument("--max-frames", type=int)
    p.add_argument("--pace", choices=PACE_CHOICES, default="mono")
    p.add_argument("--pace-rate", type=float, default=1.0)
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    try:
        stats = track_sequence(args.data, args.output, args.vocabulary, args.sensor, args.dataset,
                               args.max_frames, args.start_frame, args.pace, args.pace_rate)
    except VslamError as exc:
        log.error("%s", exc)
        return 2
    log.info("done: %d/%d frames in the %s trajectory (%d tracked online), %.1f frames/s", stats["tracked"],
             stats["frames"], stats["trajectory"], stats["tracked_online"], stats["fps"])
    return 0


if __name__ == "__main__":
    sys.exit(main())
