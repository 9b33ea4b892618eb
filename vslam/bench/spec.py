"""The benchmark spec: which sequences to run, with which settings, how many times.

A spec is a small YAML file::

    repeats: 3                      # default repeats of every run (>= 1)
    defaults:                       # optional: fields every run inherits (a run's own win)
      max_frames: 200
    runs:
      - name: kitti06-stereo        # unique; letters, digits, '.', '_' and '-' (it names a folder)
        data: ../shared/data/kitti_odometry/sequences/06
        sensor: stereo              # mono | stereo | rgbd [-inertial] (default: the richest the data has)
        set: {loop.enabled: false}  # config overrides, as `vslam run --set` (or a list of "k=v")
        # optional: max_frames, start_frame, dataset, config, repeats

Paths (``data``, ``config``) may use environment variables (``${VSLAM_SHARED_DATA}/tum_...``), with a
default for when the variable is unset or empty (``${VSLAM_SHARED_DATA:-../../shared/data}``), and ``~``;
relative paths (also a default's) resolve against the folder of the spec file, not the working directory.
An unset variable, an unknown key, a wrong type or a duplicate name raises
:class:`~vslam.errors.ConfigError` naming the spec file, the run and the field; so do ``repeats``
over :data:`MAX_REPEATS`, a ``config`` that is the spec itself, and (with ``check_paths``, as both
``vslam bench`` and its ``--dry-run`` do) a ``data`` path that is missing or a symbolic-link loop.
The file is read with YAML aliases refused and at most :data:`MAX_SPEC_BYTES` bytes.
"""
from __future__ import annotations

import errno
import json
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from vslam.errors import ConfigError
from vslam.inertial.sensors import ALL_SENSORS
from vslam.outputs import same_path
from vslam.textfile import load_yaml_text, open_text

SENSORS = ALL_SENSORS  # mono, stereo, rgbd and their -inertial variants
#: runs of one spec entry: a benchmark repeats a run a few times, never millions
MAX_REPEATS = 1000
#: a spec is a few KB
MAX_SPEC_BYTES = 1_000_000
#: overrides only the dry run's stand-in runner reads (:mod:`vslam.bench.fake`)
FAKE_PREFIX = "fake."
_TOP_KEYS = {"repeats", "runs", "defaults", "description"}
_RUN_KEYS = {"name", "data", "sensor", "set", "max_frames", "start_frame", "dataset", "config", "repeats"}
_NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]*$")
_DEFAULT_VAR_RE = re.compile(r"\$\{([A-Za-z_][A-Za-z0-9_]*):-([^}]*)\}")
_UNSET_VAR_RE = re.compile(r"\$\{?([A-Za-z_][A-Za-z0-9_]*)\}?")


@dataclass(frozen=True)
class RunSpec:
    """One entry of ``runs``: a sequence and the settings to run it with.

    Attributes:
        name: unique label, also the folder ``DIR/runs/<name>/<repeat>/``.
        data: absolute path of the sequence.
        sensor: ``mono``, ``stereo``, ``rgbd`` or None (the richest the data has).
        overrides: ``key=value`` strings, as ``vslam run --set``.
        repeats: how many times to run it.
    """

    name: str
    data: Path
    sensor: str | None = None
    dataset: str | None = None
    config: Path | None = None
    overrides: tuple[str, ...] = ()
    max_frames: int | None = None
    start_frame: int = 0
    repeats: int = 1

    def to_dict(self) -> dict:
        return {
            "name": self.name, "data": str(self.data), "sensor": self.sensor, "dataset": self.dataset,
            "config": str(self.config) if self.config else None, "overrides": list(self.overrides),
            "max_frames": self.max_frames, "start_frame": self.start_frame, "repeats": self.repeats,
        }


@dataclass(frozen=True)
class BenchSpec:
    """A parsed spec: the runs (each with its own repeat count) and where it came from."""

    runs: tuple[RunSpec, ...]
    repeats: int = 1
    source: Path | None = None
    description: str = ""

    @property
    def n_jobs(self) -> int:
        """Number of (run, repeat) executions."""
        return sum(r.repeats for r in self.runs)


def _expand_path(value: Any, where: str, base_dir: Path) -> Path:
    if not isinstance(value, str) or not value.strip():
        raise ConfigError(f"{where}: expected a path string, got {value!r}")
    expanded = _DEFAULT_VAR_RE.sub(lambda m: os.environ.get(m.group(1)) or m.group(2), value.strip())
    expanded = os.path.expanduser(os.path.expandvars(expanded))
    unset = _UNSET_VAR_RE.findall(expanded)
    if unset:
        raise ConfigError(
            f"{where}: environment variable ${unset[0]} in {value!r} is not set; export it or write the path"
        )
    path = Path(expanded)
    if not path.is_absolute():
        path = base_dir / path
    return Path(os.path.normpath(path))


def _int(value: Any, where: str, minimum: int, maximum: int | None = None) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ConfigError(f"{where}: expected an integer, got {value!r}")
    if value < minimum:
        raise ConfigError(f"{where}: must be >= {minimum}, got {value}")
    if maximum is not None and value > maximum:
        raise ConfigError(f"{where}: must be <= {maximum}, got {value}")
    return value


def _check_paths(data_path: Path, config_path: Path | None, where: str, base_dir: Path) -> None:
    """The run's ``data`` exists (a symbolic-link loop named as such) and its ``config`` is a file."""
    try:
        data_path.stat()
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise ConfigError(f"{where}.data: {data_path} is a symbolic link loop (it leads back to itself); "
                              "point it at the sequence folder") from None
        raise ConfigError(f"{where}.data: {data_path} does not exist; fix the path "
                          f"(relative paths resolve against {base_dir})") from None
    if config_path is not None and not config_path.is_file():
        raise ConfigError(f"{where}.config: {config_path} is not a file")


def _overrides(value: Any, where: str) -> tuple[str, ...]:
    """``set`` as a mapping ``{key: value}`` or a list of ``"key=value"`` strings -> ``("k=v", ...)``.

    Mapping values are written as JSON (a subset of YAML), so ``vslam.config`` parses them back to
    the same value: ``false`` stays a bool, ``"3d3d"`` a string, ``[1, 2]`` a list.
    """
    if value is None:
        return ()
    if isinstance(value, dict):
        out = []
        for k, v in value.items():
            if not isinstance(k, str) or not k:
                raise ConfigError(f"{where}: keys must be dotted setting names, got {k!r}")
            out.append(f"{k}={json.dumps(v)}")
        return tuple(out)
    if isinstance(value, (list, tuple)):
        for item in value:
            if not isinstance(item, str) or "=" not in item:
                raise ConfigError(f"{where}: list items must be 'key=value' strings, got {item!r}")
        return tuple(value)
    raise ConfigError(f"{where}: expected a mapping {{key: value}} or a list of 'key=value', got {value!r}")


def _check_config(config_path: Path | None, overrides: tuple[str, ...], where: str, fake_keys: bool = False) -> None:
    """Build the run's configuration so a typo in ``set`` fails before any run (skipped while the
    root ``vslam.config.Config`` does not exist yet); ``fake_keys``: the dry run's ``fake.*`` are no settings."""
    try:
        from vslam.config import Config, load_config
    except ImportError:
        return
    if fake_keys:
        overrides = tuple(o for o in overrides if not o.startswith(FAKE_PREFIX))
    try:
        load_config(Config, config_path if (config_path and config_path.is_file()) else None, overrides)
    except ConfigError as exc:
        raise ConfigError(f"{where}: {exc}") from None


def parse_spec(data: Any, base_dir: str | Path = ".", source: str | Path | None = None,
               check_paths: bool = False, check_config: bool = True, fake_keys: bool = False) -> BenchSpec:
    """Validate a spec already loaded from YAML (a dict) and resolve its paths.

    Args:
        data: the mapping read from the YAML file.
        base_dir: folder that relative paths resolve against (the spec file's folder).
        source: the spec file, for error messages.
        check_paths: raise when a run's ``data`` (or ``config``) does not exist.
        check_config: build each run's configuration now so a typo in ``set`` fails before any run.
        fake_keys: ``set`` may hold the dry run's ``fake.*`` keys (not checked as settings).
    """
    src = str(source) if source is not None else "benchmark spec"
    base_dir = Path(base_dir)
    if not isinstance(data, dict):
        raise ConfigError(f"{src}: expected a mapping with 'runs:' (and optional 'repeats:'), got {type(data).__name__}")
    unknown = sorted(set(data) - _TOP_KEYS)
    if unknown:
        raise ConfigError(f"{src}: unknown key(s) {', '.join(map(repr, unknown))}; valid: {', '.join(sorted(_TOP_KEYS))}")
    repeats = _int(data.get("repeats", 1), f"{src}: repeats", 1, MAX_REPEATS)
    defaults = data.get("defaults") or {}
    if not isinstance(defaults, dict):
        raise ConfigError(f"{src}: defaults must be a mapping of run fields, got {defaults!r}")
    bad = sorted(set(defaults) - (_RUN_KEYS - {"name"}))
    if bad:
        raise ConfigError(f"{src}: defaults: unknown key(s) {', '.join(map(repr, bad))}; valid: "
                          f"{', '.join(sorted(_RUN_KEYS - {'name'}))}")
    runs_raw = data.get("runs")
    if not isinstance(runs_raw, list) or not runs_raw:
        raise ConfigError(f"{src}: 'runs' must be a non-empty list of runs (each with name and data)")
    runs: list[RunSpec] = []
    seen: set[str] = set()
    for i, raw in enumerate(runs_raw):
        where = f"{src}: runs[{i}]"
        if not isinstance(raw, dict):
            raise ConfigError(f"{where}: expected a mapping with name and data, got {raw!r}")
        unknown = sorted(set(raw) - _RUN_KEYS)
        if unknown:
            raise ConfigError(f"{where}: unknown key(s) {', '.join(map(repr, unknown))}; "
                              f"valid: {', '.join(sorted(_RUN_KEYS))}")
        merged = {**defaults, **raw}
        if "set" in defaults and "set" in raw:  # overrides add up: defaults first, the run's win
            merged["set"] = list(_overrides(defaults["set"], f"{src}: defaults.set")) + \
                list(_overrides(raw["set"], f"{where}.set"))
        name = merged.get("name")
        if not isinstance(name, str) or not _NAME_RE.match(name):
            raise ConfigError(f"{where}: name must be letters, digits, '.', '_' or '-' (it names a folder), got {name!r}")
        where = f"{src}: run {name!r}"
        if name in seen:
            raise ConfigError(f"{where}: duplicate name; every run needs its own")
        seen.add(name)
        if "data" not in merged:
            raise ConfigError(f"{where}: missing 'data' (the sequence folder)")
        data_path = _expand_path(merged["data"], f"{where}.data", base_dir)
        sensor = merged.get("sensor")
        if sensor is not None and sensor not in SENSORS:
            raise ConfigError(f"{where}.sensor: {sensor!r} is not one of {', '.join(SENSORS)}")
        dataset = merged.get("dataset")
        if dataset is not None and not isinstance(dataset, str):
            raise ConfigError(f"{where}.dataset: expected a format name (tum, kitti, euroc, 7scenes, folder, video)")
        config = merged.get("config")
        config_path = _expand_path(config, f"{where}.config", base_dir) if config is not None else None
        if config_path is not None and source is not None and same_path(config_path, source):
            raise ConfigError(f"{where}.config: {config_path} is this benchmark spec itself; give a vslam settings "
                              "file (`vslam config` lists the keys)")
        max_frames = merged.get("max_frames")
        if max_frames is not None:
            max_frames = _int(max_frames, f"{where}.max_frames", 1)
        start_frame = _int(merged.get("start_frame", 0), f"{where}.start_frame", 0)
        run_repeats = _int(merged.get("repeats", repeats), f"{where}.repeats", 1, MAX_REPEATS)
        overrides = _overrides(merged.get("set"), f"{where}.set")
        if check_paths:
            _check_paths(data_path, config_path, where, base_dir)
        if check_config:
            _check_config(config_path, overrides, where, fake_keys)
        runs.append(RunSpec(name=name, data=data_path, sensor=sensor, dataset=dataset, config=config_path,
                            overrides=overrides, max_frames=max_frames, start_frame=start_frame,
                            repeats=run_repeats))
    return BenchSpec(runs=tuple(runs), repeats=repeats, source=Path(source) if source else None,
                     description=str(data.get("description", "") or ""))


def load_spec(path: str | Path, check_paths: bool = False, check_config: bool = True,
              fake_keys: bool = False) -> BenchSpec:
    """Read and validate the spec file at ``path`` (see the module docstring for the format)."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"{path}: benchmark spec not found")
    data = load_yaml_text(open_text(path, ConfigError, max_bytes=MAX_SPEC_BYTES).read(), path, ConfigError)
    return parse_spec(data, base_dir=path.resolve().parent, source=path, check_paths=check_paths,
                      check_config=check_config, fake_keys=fake_keys)


def select_runs(spec: BenchSpec, names: list[str] | None) -> BenchSpec:
    """The spec restricted to the runs named in ``names`` (all when empty)."""
    if not names:
        return spec
    known = {r.name for r in spec.runs}
    missing = [n for n in names if n not in known]
    if missing:
        raise ConfigError(f"no run named {', '.join(map(repr, missing))} in the spec; runs: {', '.join(sorted(known))}")
    return BenchSpec(runs=tuple(r for r in spec.runs if r.name in names), repeats=spec.repeats,
                     source=spec.source, description=spec.description)
