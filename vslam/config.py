"""Configuration: one frozen dataclass per stage, composed into :class:`Config`.

Defaults live in code. A YAML file overrides any subset (nested mappings mirror the dataclass
tree) and ``--set key.sub=value`` overrides single fields; values are parsed as YAML scalars
and checked against the field's type, so ``--set loop.enabled=false`` or
``--set frontend.motion=3d3d`` work and a typo gives a :class:`~vslam.errors.ConfigError`
listing the valid keys.
"""
from __future__ import annotations

import dataclasses
import types
import typing
from pathlib import Path
from typing import Any, Literal, get_args, get_origin, get_type_hints

import yaml

from vslam.errors import ConfigError
from vslam.textfile import open_text


def to_dict(cfg: Any) -> dict:
    """A nested plain-dict view of a dataclass config (tuples become lists)."""
    out = {}
    for f in dataclasses.fields(cfg):
        value = getattr(cfg, f.name)
        if dataclasses.is_dataclass(value):
            out[f.name] = to_dict(value)
        elif isinstance(value, tuple):
            out[f.name] = list(value)
        else:
            out[f.name] = value
    return out


def _coerce(value: Any, tp: Any, key: str) -> Any:
    """Check/convert ``value`` to the annotated type ``tp`` (bool, int, float, str, Literal, tuple, Optional)."""
    origin = get_origin(tp)
    if tp is Any:
        return value
    if origin is Literal:
        choices = get_args(tp)
        if value not in choices:
            raise ConfigError(f"{key}: {value!r} is not one of {', '.join(map(repr, choices))}")
        return value
    if origin in (typing.Union, types.UnionType):
        args = get_args(tp)
        if value is None and type(None) in args:
            return None
        errors = []
        for arg in args:
            if arg is type(None):
                continue
            try:
                return _coerce(value, arg, key)
            except ConfigError as exc:
                errors.append(str(exc))
        raise ConfigError(errors[0] if errors else f"{key}: invalid value {value!r}")
    if origin in (tuple, list):
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{key}: expected a list, got {value!r}")
        args = get_args(tp)
        if origin is tuple and len(args) == 2 and args[1] is Ellipsis:
            return tuple(_coerce(v, args[0], key) for v in value)
        if origin is tuple and args:
            if len(args) != len(value):
                raise ConfigError(f"{key}: expected {len(args)} values, got {len(value)}")
            return tuple(_coerce(v, a, key) for v, a in zip(value, args))
        return type(value)(value) if origin is list else tuple(value)
    if tp is bool:
        if isinstance(value, bool):
            return value
        raise ConfigError(f"{key}: expected true or false, got {value!r}")
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            if isinstance(value, float) and value.is_integer():
                return int(value)
            raise ConfigError(f"{key}: expected an integer, got {value!r}")
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{key}: expected a number, got {value!r}")
        if value != value:  # NaN compares false everywhere and would silently disable a check
            raise ConfigError(f"{key}: expected a number, got NaN")
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            return str(value)
        return value
    if dataclasses.is_dataclass(tp):
        if isinstance(value, tp):
            return value
        if not isinstance(value, dict):
            raise ConfigError(f"{key}: expected a mapping of settings, got {value!r}")
        return from_dict(tp, value, prefix=key + ".")
    return value


def from_dict(cls: type, data: dict | None, prefix: str = "", base: Any = None) -> Any:
    """Build dataclass ``cls`` from a (partial) nested dict, on top of ``base`` or the defaults."""
    data = data or {}
    if not isinstance(data, dict):
        raise ConfigError(f"{prefix.rstrip('.') or 'config'}: expected a mapping, got {data!r}")
    base = base if base is not None else cls()
    hints = get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = set(data) - names
    if unknown:
        raise ConfigError(
            f"unknown setting {prefix}{sorted(unknown)[0]}; valid keys here: {', '.join(sorted(names))}"
        )
    changes = {}
    for name, value in data.items():
        tp = hints[name]
        current = getattr(base, name)
        if dataclasses.is_dataclass(current) and isinstance(value, dict):
            changes[name] = from_dict(type(current), value, prefix=f"{prefix}{name}.", base=current)
        else:
            changes[name] = _coerce(value, tp, prefix + name)
    try:
        return dataclasses.replace(base, **changes)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{prefix.rstrip('.') or 'config'}: {exc}") from None


def parse_override(text: str) -> tuple[list[str], Any]:
    """``"a.b=value"`` -> (["a", "b"], value parsed as a YAML scalar)."""
    if "=" not in text:
        raise ConfigError(f"--set expects key=value, got {text!r}")
    key, raw = text.split("=", 1)
    key = key.strip()
    if not key:
        raise ConfigError(f"--set expects key=value, got {text!r}")
    try:
        value = yaml.safe_load(raw) if raw.strip() else ""
    except yaml.YAMLError:
        value = raw
    return key.split("."), value


def nest(path: list[str], value: Any) -> dict:
    out: Any = value
    for part in reversed(path):
        out = {part: out}
    return out


def load_config(cls: type, path: str | Path | None = None, overrides: list[str] | tuple[str, ...] = ()) -> Any:
    """Defaults of ``cls``, then the YAML file at ``path``, then each ``key=value`` override."""
    cfg = cls()
    if path is not None:
        path = Path(path)
        if not path.is_file():
            raise ConfigError(f"{path}: config file not found")
        try:
            data = yaml.safe_load(open_text(path, ConfigError).read()) or {}
        except yaml.YAMLError as exc:
            raise ConfigError(f"{path}: not valid YAML ({exc})") from None
        try:
            cfg = from_dict(cls, data, base=cfg)
        except ConfigError as exc:
            raise ConfigError(f"{path}: {exc}") from None
    for text in overrides:
        key, value = parse_override(text)
        cfg = from_dict(cls, nest(key, value), base=cfg)
    return cfg


def dump_config(cfg: Any, path: str | Path) -> None:
    """Write the fully resolved configuration as YAML."""
    Path(path).write_text(yaml.safe_dump(to_dict(cfg), sort_keys=False))


# --------------------------------------------------------------------------- the root configuration
from dataclasses import dataclass, field  # noqa: E402

from vslam.backend.config import BackendConfig  # noqa: E402,F401  (re-exported: vslam.config.BackendConfig)
from vslam.features.config import FeatureConfig  # noqa: E402
from vslam.frontend.config import FrontendConfig  # noqa: E402
from vslam.loop.config import LoopConfig  # noqa: E402


@dataclass(frozen=True)
class Config:
    """Everything a run is configured by, one section per pipeline stage."""

    features: FeatureConfig = field(default_factory=FeatureConfig)
    frontend: FrontendConfig = field(default_factory=FrontendConfig)
    backend: BackendConfig = field(default_factory=BackendConfig)
    loop: LoopConfig = field(default_factory=LoopConfig)
