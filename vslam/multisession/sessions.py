"""The sessions of ``vslam map``: what ``INPUTS`` name, and one session's run as a task.

``INPUTS`` are recordings (any path ``vslam run`` reads; the session is named after the folder or
file, ``-2``, ``-3`` ... added to repeated names) or one YAML file::

    sessions:
      - {name: kitchen_a, data: ../shared/data/7scenes_redkitchen, sensor: rgbd, max_frames: 250}
      - {name: kitchen_b, data: ../shared/data/7scenes_redkitchen, start_frame: 200, max_frames: 250}

(every key but ``data`` optional; relative ``data`` / ``camera`` paths are relative to the file).
Each session runs :func:`vslam.api.run_path` into ``OUT/sessions/<name>/`` (:func:`run_session`,
a picklable top-level function for a process pool or a Ray task), without its per-run plots
(``trajectory.png``, ``topology.png``: about half a second of matplotlib per session, as long as
tracking a fleet session; the report of ``vslam map`` draws every session). A folder holding a finished run
of the same session (``stats.json`` without ``error``, same ``path``, ``sensor`` and ``start_frame``,
a ``map/``) is reused instead (:func:`reusable`): a rerun resumes where the last one stopped.
"""
from __future__ import annotations

import json
import os
import re
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from vslam.errors import ConfigError

#: session names become folder names
NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,99}$")
SPEC_KEYS = ("name", "data", "sensor", "camera", "start_frame", "max_frames")
SENSORS = ("mono", "stereo", "rgbd")
MAX_SESSIONS_FILE_BYTES = 1 << 20


@dataclass(frozen=True)
class SessionSpec:
    """One recording to map: ``data`` (a dataset path), optional ``sensor``, ``camera`` file, frames."""

    name: str
    data: str
    sensor: str | None = None
    camera: str | None = None
    start_frame: int = 0
    max_frames: int | None = None

    def record(self) -> dict:
        return asdict(self)


def _int(value: Any, where: str, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise ConfigError(f"{where}: expected an integer >= {minimum}, got {value!r}")
    return value


def _path(value: Any, where: str, base: Path) -> str:
    if not isinstance(value, str) or not value.strip():
        raise ConfigError(f"{where}: expected a path, got {value!r}")
    p = Path(value.strip()).expanduser()
    return str(p if p.is_absolute() else base / p)


def _unique(name: str, taken: set[str]) -> str:
    out, k = name, 2
    while out in taken:
        out, k = f"{name}-{k}", k + 1
    return out


def _default_name(data: str) -> str:
    p = Path(data)
    name = re.sub(r"[^A-Za-z0-9._-]", "_", (p.stem if p.suffix else p.name) or "session").lstrip("._-")
    return name or "session"


def _parse_entry(entry: Any, where: str, base: Path, taken: set[str]) -> SessionSpec:
    if not isinstance(entry, dict):
        raise ConfigError(f"{where}: expected a mapping with at least 'data', got {entry!r}")
    unknown = sorted(set(entry) - set(SPEC_KEYS))
    if unknown:
        raise ConfigError(f"{where}: unknown key {unknown[0]!r}; a session has {', '.join(SPEC_KEYS)}")
    if "data" not in entry:
        raise ConfigError(f"{where}: 'data' (the recording's path) is missing")
    data = _path(entry["data"], f"{where}.data", base)
    name = entry.get("name")
    if name is None:
        name = _unique(_default_name(data), taken)
    elif not isinstance(name, str) or not NAME_RE.match(name):
        raise ConfigError(f"{where}.name: {name!r} is not a usable folder name (letters, digits, . _ -)")
    if name in taken:
        raise ConfigError(f"{where}.name: {name!r} is used twice; session names must be unique")
    sensor = entry.get("sensor")
    if sensor is not None and sensor not in SENSORS:
        raise ConfigError(f"{where}.sensor: {sensor!r}; vslam map merges {', '.join(SENSORS)} sessions")
    camera = entry.get("camera")
    camera = None if camera is None else (camera if camera in ("fr1", "fr2", "fr3") else
                                          _path(camera, f"{where}.camera", base))
    start = _int(entry.get("start_frame", 0), f"{where}.start_frame", 0)
    max_frames = entry.get("max_frames")
    max_frames = None if max_frames is None else _int(max_frames, f"{where}.max_frames", 1)
    taken.add(name)
    return SessionSpec(name, data, sensor, camera, start, max_frames)


def is_sessions_file(path: str | Path) -> bool:
    p = Path(path)
    return p.is_file() and p.suffix.lower() in (".yaml", ".yml")


def parse_inputs(inputs: list[str], sensor: str | None = None, taken: set[str] | None = None) -> list[SessionSpec]:
    """The sessions named by ``INPUTS`` (see the module docstring); ``sensor`` is the default sensor;
    ``taken``: names already in use (sessions of an existing result)."""
    from vslam.textfile import load_yaml_text, open_text

    if not inputs:
        raise ConfigError("no inputs: give recordings or one sessions YAML file")
    taken = set(taken or ())
    if len(inputs) == 1 and is_sessions_file(inputs[0]):
        path = Path(inputs[0])
        doc = load_yaml_text(open_text(path, ConfigError, max_bytes=MAX_SESSIONS_FILE_BYTES).read(), path, ConfigError)
        if not isinstance(doc, dict) or not isinstance(doc.get("sessions"), list) or not doc["sessions"]:
            raise ConfigError(f"{path}: expected 'sessions:' with a list of {{name, data, sensor, camera, "
                              "start_frame, max_frames}}")
        base = path.resolve().parent
        specs = []
        for i, e in enumerate(doc["sessions"]):
            spec = _parse_entry(e, f"{path}: sessions[{i}]", base, taken)
            specs.append(spec if spec.sensor or not sensor else SessionSpec(**{**spec.record(), "sensor": sensor}))
        return specs
    if any(is_sessions_file(p) for p in inputs):
        raise ConfigError("a sessions YAML file must be the only input")
    return [_parse_entry({"data": p, "sensor": sensor}, f"input {p}", Path.cwd(), taken) for p in inputs]


# ============================================================================ one session (a task)
def _summary(stats: dict) -> dict:
    keys = ("frames", "tracked", "lost", "keyframes", "map_points", "sensor", "ate_rmse", "wall_s", "fps", "segments")
    return {k: stats[k] for k in keys if k in stats}


def reusable(spec: SessionSpec, folder: Path) -> dict | None:
    """The ``stats.json`` of a finished run of ``spec`` in ``folder``, or None (see the module docstring)."""
    try:
        stats = json.loads((folder / "stats.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(stats, dict) or stats.get("error") or not (folder / "map" / "map.json").is_file():
        return None
    try:
        same_path = Path(stats.get("path", "")).resolve() == Path(spec.data).resolve()
    except (OSError, RuntimeError):
        return None
    same = (same_path and stats.get("start_frame", 0) == spec.start_frame
            and (spec.sensor is None or stats.get("sensor") == spec.sensor)
            and (spec.max_frames is None or int(stats.get("frames", 0)) <= spec.max_frames))
    return stats if same else None


def reused_record(spec: SessionSpec, folder: Path, stats: dict) -> dict:
    """The record of a session whose finished run in ``folder`` is reused."""
    return {"name": spec.name, "spec": spec.record(), "folder": str(folder), "status": "ok", "reused": True,
            "error": None, **_summary(stats)}


def run_session(spec: SessionSpec, folder: str, config: str | None = None, overrides: tuple[str, ...] = (),
                prefetch: str = "thread") -> dict:
    """Run one session into ``folder`` (or reuse a finished run there); never raises: a failure is
    the record's ``status: failed`` and ``error``. ``prefetch``: ``thread`` (frames decoded and
    detected in a second thread: a task then keeps more than one core busy) or ``none``
    (:func:`session_prefetch`)."""
    from vslam.api import run_path

    out = Path(folder)
    record: dict[str, Any] = {"name": spec.name, "spec": spec.record(), "folder": str(out)}
    done = reusable(spec, out)
    if done is not None:
        return reused_record(spec, out, done)
    t0 = time.perf_counter()
    try:
        result = run_path(spec.data, out, sensor=spec.sensor, config=config, overrides=list(overrides),
                          max_frames=spec.max_frames, start_frame=spec.start_frame, camera=spec.camera,
                          prefetch=prefetch, plots=False)  # the report draws every session
        stats = dict(result.stats)
        if not (out / "map" / "map.json").is_file() or not stats.get("keyframes"):
            raise ConfigError(f"{spec.data}: the run made no map (no keyframes)")
    except BaseException as exc:  # noqa: BLE001 - a failed session is recorded, the others go on
        if isinstance(exc, KeyboardInterrupt):
            raise
        return {**record, "status": "failed", "reused": False, "error": f"{type(exc).__name__}: {exc}",
                "task_s": round(time.perf_counter() - t0, 2)}
    return {**record, "status": "ok", "reused": False, "error": None, **_summary(stats),
            "task_s": round(time.perf_counter() - t0, 2)}


def session_prefetch(kind: str, workers: int, cpus: int | None = None) -> str:
    """The prefetch mode of a session task: ``thread`` only where each task has a second core to
    itself (local executor, ``2 x workers <= cpus``); otherwise ``none``, so that ``workers`` tasks
    side by side do not fight over the cores with their prefetch threads (a Ray task asks for one
    CPU). Measured on 2 cores, 16 sessions (benchmarks/RESULTS.md, issue #26): with their prefetch
    threads 2 tasks side by side tracked in 0.73x the sequential time instead of about 0.6x."""
    cpus = cpus if cpus is not None else (os.cpu_count() or 1)
    return "thread" if kind == "local" and 2 * max(workers, 1) <= cpus else "none"


def session_prefetches(kind: str, workers: int, n: int, cpus: int | None = None) -> list[str]:
    """The prefetch mode of each of ``n`` session tasks, in the order they start:
    :func:`session_prefetch`, except for a last wave with fewer tasks than workers. The last
    ``n % workers`` tasks run beside idle workers, and each gets a prefetch thread when there is an
    idle core for every one of them (``2 x tail <= workers``, and ``workers <= cpus`` for the local
    executor). Example: 5 sessions on 2 workers, the fifth runs alone on both cores (7-Scenes, 280
    frames: 2.9 s instead of 4.3-5.0 s, the same trajectory).

    Such a task asks Ray for one CPU, like the others, and takes the second core as the other
    workers finish. Asking for two put it in a scheduling class of its own, which Ray does not keep
    in submission order: on the 16-arc fleet it started second, and one worker stood idle while it
    waited for both CPUs and ran (0.49 s; the tracking stage 6.61 -> 6.32 s on average over three
    alternated runs, benchmarks/RESULTS.md round 14)."""
    cpus = cpus if cpus is not None else (os.cpu_count() or 1)
    modes = [session_prefetch(kind, workers, cpus)] * n
    tail = n % max(workers, 1)
    if tail and 2 * tail <= workers and (kind == "ray" or workers <= cpus):
        modes[n - tail:] = ["thread"] * tail
    return modes


def previous_sessions(result_dir: str | Path) -> list[SessionSpec]:
    """The sessions of an earlier ``vslam map`` result (its ``sessions.json``), to add new ones to."""
    path = Path(result_dir) / "sessions.json"
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
        return [SessionSpec(**s["spec"]) for s in doc["sessions"]]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ConfigError(f"{path}: not readable as the sessions of a `vslam map` result ({exc}); give the "
                          "output folder of an earlier `vslam map`") from None
