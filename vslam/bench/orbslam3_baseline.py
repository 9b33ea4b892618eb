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
* unpaced monocular mapping cannot keep up on 2 cores: by default (``pace="mono"``) monocular and
  inertial runs are fed at the sensor rate times ``pace_rate`` (default 1), which caps their
  frames/s at that rate (``stats["paced"]``). On a loaded machine even the sensor rate is too fast
  (measured: KITTI 07 at load ~8 resets its map twice at 10 Hz, tracks 156/160 frames at 4 Hz):
  lower ``pace_rate``. Unpaced, ORB-SLAM3's mono-inertial mapping resets over and over on 2 cores;
* the inertial sensors run ORB-SLAM3's ``IMU_MONOCULAR`` / ``IMU_STEREO`` / ``IMU_RGBD`` modes with
  the sequence's IMU (:mod:`vslam.bench.orbslam3_io`: samples per frame, the settings' ``Tbc`` and
  noise block, and the saved trajectory, which holds IMU poses, turned into the camera's).
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

from vslam.bench.orbslam3_io import read_euroc_ns, settings_yaml  # noqa: F401 - re-exported
from vslam.errors import VslamError
from vslam.inertial.sensors import ALL_SENSORS

log = logging.getLogger(__name__)

NAME = "orbslam3"
#: environment variable naming the Python interpreter that has pyorbslam3
PYTHON_ENV = "VSLAM_ORBSLAM3_PYTHON"
#: environment variable naming the DBoW2 text vocabulary (pyorbslam3's own convention)
VOCAB_ENV = "PYORBSLAM3_VOCAB"
#: which sensors are fed at the sensor rate: ``mono`` (default: monocular and inertial), ``all`` or ``none``
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
    from vslam.errors import TrajectoryError
    from vslam.trajectory import read_trajectory

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
    try:  # a run that kept no pose writes an empty trajectory: no evaluation then
        traj = read_trajectory(traj_path) if traj_path.is_file() and traj_path.stat().st_size else None
    except TrajectoryError:
        traj = None
    stats.update(_evaluate(traj, path, dataset, stats.get("sensor", sensor)))
    (out / "stats.json").write_text(json.dumps(stats, indent=2))
    return stats


def _evaluate(traj: Any, path: str | Path, dataset: str | None, sensor: str | None) -> dict:
    """ATE/RPE of the baseline's trajectory as for a vslam run of ``sensor`` (Sim(3) for ``mono``,
    SE(3) otherwise: mono-inertial is metric); mono-inertial adds the Sim(3) ATE and scale
    (``ate_rmse_sim3``, ``scale_sim3``)."""
    from vslam.datasets import open_dataset
    from vslam.inertial.sensors import split_sensor
    from vslam.runner import trajectory_errors

    ds = open_dataset(path, kind=dataset, sensor=split_sensor(sensor)[0] if sensor else None)
    gt = ds.ground_truth()
    if gt is None or traj is None or len(traj) < 3:
        return {}
    errors = trajectory_errors(traj, gt, "sim3" if sensor == "mono" else "se3")
    if sensor == "mono-inertial":
        sim3 = trajectory_errors(traj, gt, "sim3")
        errors.update(ate_rmse_sim3=sim3.get("ate_rmse"), scale_sim3=sim3.get("scale"))
    return errors


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


def _track(slam: Any, sensor: str, frame: Any, imu: np.ndarray | None = None) -> np.ndarray | None:
    """One tracking call of ``pyorbslam3.Slam`` (``sensor``: the visual base sensor; ``imu``: the
    frame's IMU samples in an inertial mode); ``T_world_cam`` (its ``pose_wc``) or None.

    ``pose_valid`` is true for ORB-SLAM3's OK and RECENTLY_LOST states; otherwise ORB-SLAM3
    reports no pose, and the frame counts as lost.
    """
    kw = {} if imu is None else {"imu": imu}
    if sensor == "rgbd":
        res = slam.track_rgbd(frame.image, frame.depth.astype(np.float32), frame.timestamp, **kw)
    elif sensor == "stereo":
        res = slam.track_stereo(frame.image, frame.image_right, frame.timestamp, **kw)
    else:
        res = slam.track_monocular(frame.image, frame.timestamp, **kw)
    if not getattr(res, "pose_valid", False) or getattr(res, "pose_wc", None) is None:
        return None
    T = np.asarray(res.pose_wc, dtype=float)
    return T if T.shape == (4, 4) and np.all(np.isfinite(T)) else None


def _open_child_dataset(path: str | Path, dataset: str | None, sensor: str | None):
    """``(dataset, sensor, base sensor, IMU calibration or None, ImuFeeder or None)`` of the run."""
    from vslam.bench.orbslam3_io import ImuFeeder, imu_for
    from vslam.datasets import open_dataset
    from vslam.inertial.sensors import split_sensor

    probe = open_dataset(path, kind=dataset)
    if sensor is None:
        sensor = next((s for s in ("rgbd", "stereo", "mono") if s in probe.sensors), None)
    base, inertial = split_sensor(sensor) if sensor else (None, False)
    if base not in probe.sensors:
        raise VslamError(f"{path} provides {', '.join(probe.sensors)}; it cannot be run as {sensor!r}")
    ds = open_dataset(path, kind=dataset, sensor=base)
    if not inertial:
        return ds, sensor, base, None, None
    imu, calib = imu_for(ds)
    log.info("IMU: %d samples from %s, T_imu_cam translation %s m", len(imu), imu.source,
             np.round(calib.T_imu_cam[:3, 3], 4).tolist())
    return ds, sensor, base, calib, ImuFeeder(imu, calib.time_offset)


def _feed(slam: Any, ds: Any, base: str, start: int, stop: int, period: float, feeder: Any) -> dict:
    """Feed frames ``start:stop`` (paced at ``period`` s when > 0); the online poses (inertial: only
    those after ORB-SLAM3's IMU initialization), per-frame tracking times and the IMU init frame."""
    ts, poses, track_ms = [], [], []
    n, init_frame, init_t = 0, None, None
    t_first = None
    for frame in ds.frames(start, stop):
        t_frame = time.perf_counter()
        t_first = frame.timestamp if t_first is None else t_first
        T_world_cam = _track(slam, base, frame, None if feeder is None else feeder.chunk(frame.timestamp))
        track_ms.append(1e3 * (time.perf_counter() - t_frame))
        n += 1
        if feeder is not None and init_frame is None and slam.time_from_imu_init() > 0:
            init_frame, init_t = n - 1, frame.timestamp - t_first
        if T_world_cam is not None and (feeder is None or init_frame is not None):
            ts.append(frame.timestamp)
            poses.append(T_world_cam)
        if n % 100 == 0:
            log.info("frame %d: %d tracked", n, len(ts))
        if period:
            time.sleep(max(0.0, period - (time.perf_counter() - t_frame)))
    return {"n": n, "ts": ts, "poses": poses, "track_ms": track_ms, "init_frame": init_frame, "init_t": init_t}


def _saved_trajectory(slam: Any, out: Path, online: Any, calib: Any) -> tuple[Any, str]:
    """ORB-SLAM3's own final trajectory (``save_trajectory_euroc``; an IMU mode saves body poses,
    turned into the camera's), else the online poses; ``(trajectory, "final" | "online")``."""
    from vslam.bench.orbslam3_io import body_to_camera

    euroc_path = out / "orbslam3_trajectory_euroc.txt"
    final = None
    try:
        slam.save_trajectory_euroc(str(euroc_path))  # the final (loop-corrected) poses, mono included
        final = read_euroc_ns(euroc_path)
    except Exception as exc:  # keep the online poses
        log.warning("save_trajectory_euroc failed: %s", exc)
    if final is not None and len(final) and calib is not None:
        final = body_to_camera(final, calib.T_imu_cam)
    return (final, "final") if final is not None and len(final) else (online, "online")


def track_sequence(path: str | Path, output: str | Path, vocabulary: str | Path, sensor: str | None = None,
                   dataset: str | None = None, max_frames: int | None = None, start_frame: int = 0,
                   pace: str = "mono", pace_rate: float = 1.0) -> dict:
    """The child's work: feed the sequence to ORB-SLAM3, write ``trajectory.txt`` and
    ``orbslam3_stats.json`` into ``output``; returns the stats (no evaluation here).

    ``fps`` is frames / ``wall_s``, where ``wall_s`` covers reading the frames, tracking and
    ``shutdown()`` (ORB-SLAM3 finishing local mapping and loop closing), as for a vslam run;
    loading the vocabulary is ``init_s``. ``track_ms_*`` is the time spent in the tracking calls.
    An inertial sensor runs ORB-SLAM3's IMU mode (:mod:`vslam.bench.orbslam3_io`).
    """
    from vslam.bench.orbslam3_io import orb_sensor
    from vslam.trajectory import Trajectory, write_tum

    orb = _import_pyorbslam3()
    out = Path(output)
    out.mkdir(parents=True, exist_ok=True)
    ds, sensor, base, calib, feeder = _open_child_dataset(path, dataset, sensor)
    settings = out / "orbslam3_settings.yaml"
    settings.write_text(settings_yaml(ds.camera, base, ds.frame_rate, imu_calibration=calib))
    kind = orb_sensor(orb, sensor)
    t_init = time.perf_counter()
    slam = orb.Slam(str(vocabulary), str(settings), kind, use_viewer=False)
    init_s = time.perf_counter() - t_init
    stop = len(ds) if max_frames is None else min(len(ds), start_frame + max_frames)
    paced = pace == "all" or (pace == "mono" and (base == "mono" or calib is not None))
    period = 1.0 / (ds.frame_rate * pace_rate) if paced and ds.frame_rate else 0.0
    t0 = time.perf_counter()
    try:
        fed = _feed(slam, ds, base, start_frame, stop, period, feeder)
    finally:
        t_shutdown = time.perf_counter()
        slam.shutdown()
        shutdown_s = time.perf_counter() - t_shutdown
    wall, n, ts = time.perf_counter() - t0, fed["n"], fed["ts"]
    online = Trajectory(np.asarray(ts, float), np.asarray(fed["poses"], float).reshape(-1, 4, 4))
    write_tum(out / "trajectory_online.txt", online)
    traj, source = _saved_trajectory(slam, out, online, calib)
    write_tum(out / "trajectory.txt", traj)
    track = np.asarray(fed["track_ms"]) if fed["track_ms"] else np.zeros(1)
    # tracked = poses in the evaluated trajectory: ORB-SLAM3's saved trajectory drops frames of
    # maps it reset or did not keep; tracked_online counts the frames its tracking gave a pose
    # (inertial: after its IMU initialization)
    stats = {"frames": n, "tracked": len(traj), "lost": n - len(traj), "tracked_online": len(ts),
             "wall_s": round(wall, 3),
             "fps": round(n / wall, 2) if wall > 0 else 0.0, "init_s": round(init_s, 3),
             "shutdown_s": round(shutdown_s, 3), "track_ms_mean": round(float(track.mean()), 2),
             "track_ms_median": round(float(np.median(track)), 2), "loops": [], "sensor": sensor,
             "dataset": ds.kind, "path": str(path), "start_frame": start_frame, "system": NAME,
             "paced": paced, "pace_rate": pace_rate if paced else None, "frame_rate": round(float(ds.frame_rate), 4) if ds.frame_rate else None,
             "trajectory": source, "vocabulary": str(vocabulary)}
    if feeder is not None:
        stats.update(imu_samples=feeder.fed, imu_initialized=fed["init_frame"] is not None,
                     imu_init_frame=fed["init_frame"],
                     imu_init_s=None if fed["init_t"] is None else round(float(fed["init_t"]), 3))
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
    p.add_argument("--sensor", choices=ALL_SENSORS)
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
