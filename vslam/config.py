"""Configuration: one frozen dataclass per stage, composed into :class:`Config`.

Defaults live in code. A YAML file overrides any subset (nested mappings mirror the dataclass
tree) and ``--set key.sub=value`` overrides single fields; values are parsed as YAML scalars
(aliases refused, files over :data:`MAX_CONFIG_BYTES` too) and checked against the field's type and
its declared range (``param(..., bounds="[1, 32]")``), so ``--set loop.enabled=false`` or
``--set frontend.motion=3d3d`` work and a typo gives a :class:`~vslam.errors.ConfigError`
listing the valid keys. Sections nest per concern (``--set frontend.keyframes.max_frames=5``);
the old flat keys a section replaced (``frontend.kf_max_frames``) still load, with a warning.

Every field is declared with :func:`vslam.param.param` and a one-line doc: :func:`iter_settings`
lists them, ``vslam config`` prints them and ``docs/settings.md`` is :func:`settings_markdown`.
"""
from __future__ import annotations

import dataclasses
import logging
import re
import types
import typing
from pathlib import Path
from typing import Any, Literal, get_args, get_origin, get_type_hints

import yaml

from vslam.errors import ConfigError
from vslam.param import Bounds, bounds_of, doc_of, param, section

log = logging.getLogger(__name__)
from vslam.textfile import load_yaml_text, open_text

#: a settings file is a few KB; larger is not one (and is not parsed)
MAX_CONFIG_BYTES = 1_000_000


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
    fields = {f.name: f for f in dataclasses.fields(cls)}
    names = set(fields)
    data = _nest_flat_keys(cls, _expand_dotted(data, prefix), prefix)
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
            _check_range(cls, fields[name], changes[name], prefix + name)  # before the section's own checks
    try:
        out = dataclasses.replace(base, **changes)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{prefix.rstrip('.') or 'config'}: {exc}") from None
    return out


def _bounds(cls: type, f: dataclasses.Field) -> Bounds | None:
    return bounds_of(f) or _BOUNDS_DECLARED_HERE.get(cls, {}).get(f.name)


def _check_range(cls: type, f: dataclasses.Field, value: Any, key: str) -> None:
    b = _bounds(cls, f)
    if b is not None and not b.contains(value):
        raise ConfigError(f"{key}={format_value(value)} is out of range: valid values are {b.text} ({doc_of(f)})")


def check_bounds(cfg: Any, prefix: str = "") -> None:
    """Raise :class:`ConfigError` (naming the key and its range) for the first setting of ``cfg``
    outside the range declared with :func:`vslam.param.param` (``bounds``); :func:`from_dict`
    checks each value it sets the same way."""
    for f in dataclasses.fields(cfg):
        value = getattr(cfg, f.name)
        if dataclasses.is_dataclass(value):
            check_bounds(value, f"{prefix}{f.name}.")
        else:
            _check_range(type(cfg), f, value, prefix + f.name)


def _expand_dotted(data: dict, prefix: str = "") -> dict:
    """Dotted keys (``features.n_features: 1000``, the form ``vslam config`` prints) nested one
    level (``features: {n_features: 1000}``; deeper dots are expanded by the section they land in),
    merged with the nested keys beside them; a setting given both ways is refused."""
    if not any(isinstance(k, str) and "." in k for k in data):
        return data
    out = {k: v for k, v in data.items() if not (isinstance(k, str) and "." in k)}
    for key, value in data.items():
        if not (isinstance(key, str) and "." in key):
            continue
        head, rest = key.split(".", 1)
        section = out.get(head, {})
        if not isinstance(section, dict):
            raise ConfigError(f"{prefix}{head} is given as a value and {prefix}{key} as one of its settings; keep one")
        if rest in section:
            raise ConfigError(f"setting {prefix}{key} is given twice (nested and dotted); keep one")
        out[head] = {**section, rest: value}
    return out


def flat_key_map(cls: type) -> dict[str, tuple[str, str]]:
    """Old flat keys of ``cls`` -> (section, key) of the nested section that replaced them.

    Derived from the ``flat_prefixes`` of each :func:`vslam.param.section` field: a section ``s``
    with prefix ``p`` took over the old field ``p + name`` for each of its fields ``name``; its
    ``flat_keys`` name the old fields that follow no prefix.
    """
    out: dict[str, tuple[str, str]] = {}
    for f in dataclasses.fields(cls):
        for old, name in f.metadata.get("flat_keys", {}).items():
            out.setdefault(old, (f.name, name))
        for prefix in f.metadata.get("flat_prefixes", ()):
            for g in dataclasses.fields(f.default_factory):  # type: ignore[arg-type]
                out.setdefault(prefix + g.name, (f.name, g.name))
    return out


def _nest_flat_keys(cls: type, data: dict, prefix: str) -> dict:
    """Move old flat keys (``frontend.kf_max_frames``) to their nested section, with a warning."""
    names = {f.name for f in dataclasses.fields(cls)}
    old = [k for k in data if k not in names]
    if not old:
        return data
    mapping = flat_key_map(cls)
    out = dict(data)
    for key in old:
        if key not in mapping:
            continue
        sec, name = mapping[key]
        value = out.pop(key)
        target = out.get(sec)
        if target is None:
            target = out[sec] = {}
        elif not isinstance(target, dict):
            continue
        else:
            target = out[sec] = dict(target)
        target.setdefault(name, value)
        log.warning("setting %s%s is deprecated; use %s%s.%s", prefix, key, prefix, sec, name)
    return out


@dataclasses.dataclass(frozen=True)
class Setting:
    """One leaf setting: its dotted key, default value, type and one-line doc."""

    key: str
    default: Any
    type: str
    doc: str
    bounds: str = ""  # the valid range, "[1, 32]" ('' for settings that are not numbers)


def _type_name(tp: Any) -> str:
    if get_origin(tp) is Literal:
        return "|".join(str(a) for a in get_args(tp))
    name = getattr(tp, "__name__", None)
    return name if name and get_origin(tp) is None else str(tp).replace("typing.", "")


def iter_settings(cls: type, prefix: str = "") -> list[Setting]:
    """Every leaf setting of the dataclass tree ``cls`` (dotted keys, defaults of ``cls()``)."""
    out = []
    base = cls()
    hints = get_type_hints(cls)
    for f in dataclasses.fields(cls):
        value = getattr(base, f.name)
        if dataclasses.is_dataclass(value):
            out += iter_settings(type(value), f"{prefix}{f.name}.")
        else:
            b = _bounds(cls, f)
            out.append(Setting(prefix + f.name, value, _type_name(hints[f.name]), doc_of(f), b.text if b else ""))
    return out


def iter_sections(cls: type, prefix: str = "") -> list[tuple[str, str]]:
    """(dotted key, doc) of every nested section of ``cls``: its field doc, else its class docstring."""
    out = []
    base = cls()
    for f in dataclasses.fields(cls):
        value = getattr(base, f.name)
        if dataclasses.is_dataclass(value):
            doc = doc_of(f) or (type(value).__doc__ or "").strip().splitlines()[0]
            out.append((prefix + f.name, doc))
            out += iter_sections(type(value), f"{prefix}{f.name}.")
    return out


def format_value(value: Any) -> str:
    """A default as it would be written in a YAML config file (``true``, ``null``, ``.inf``, ``[1, 2]``)."""
    if isinstance(value, tuple):
        value = list(value)
    text = yaml.safe_dump(value, default_flow_style=True, width=10**6).strip()
    return text[:-3].strip() if text.endswith("...") else text


def settings_text(cls: type, only: str = "") -> str:
    """Every setting of ``cls`` as ``key = default  doc`` lines (those under ``only`` if given)."""
    rows = [s for s in iter_settings(cls) if not only or s.key == only or s.key.startswith(only + ".")]
    width = max((len(f"{s.key} = {format_value(s.default)}") for s in rows), default=0)
    return "".join(f"{f'{s.key} = {format_value(s.default)}':<{width}}  # {s.doc}"
                   f"{f'; valid {s.bounds}' if s.bounds else ''}\n" for s in rows)


def settings_markdown(cls: type) -> str:
    """``docs/settings.md``: one table per section, every key with its type, default and doc."""
    docs = dict(iter_sections(cls))
    lines = [
        "# Settings",
        "",
        "<!-- Generated by `vslam config --markdown > docs/settings.md` from the config dataclasses "
        "(vslam/*/config.py); do not edit by hand. tests/cli/test_config_cmd.py fails when it is stale. -->",
        "",
        "Every setting with its default and, for a number, its valid range (brackets include the end, "
        "parentheses exclude it; a value outside is refused with the key and the range). Override in a YAML file (`vslam run --config FILE`, nested like the "
        "keys) or with `--set key=value` (e.g. `--set frontend.keyframes.max_frames=10`); `vslam run` writes "
        "the resolved `config.yaml` next to its results. `vslam config` prints this list.",
        "",
    ]
    groups: dict[str, list[Setting]] = {}
    for s in iter_settings(cls):
        groups.setdefault(s.key.rsplit(".", 1)[0] if "." in s.key else "", []).append(s)
    for section_key, rows in groups.items():
        title = f"{'#' * min(section_key.count('.') + 2, 4)} `{section_key}`"
        lines += [title + (f": {docs[section_key]}" if docs.get(section_key) else ""), "",
                  "| key | type | default | range | description |", "|---|---|---|---|---|"]
        for s in rows:
            key = s.key[len(section_key) + 1:] if section_key else s.key
            lines.append(f"| `{key}` | {s.type.replace('|', ' or ')} | `{format_value(s.default)}` | "
                         f"{s.bounds and f'`{s.bounds}`'} | {s.doc.replace('|', '/')} |")
        lines.append("")
    return "\n".join(lines).rstrip("\n") + "\n"


def parse_override(text: str) -> tuple[list[str], Any]:
    """``"a.b=value"`` -> (["a", "b"], value parsed as a YAML scalar)."""
    if "=" not in text:
        raise ConfigError(f"--set expects key=value, got {text!r}")
    key, raw = text.split("=", 1)
    key = key.strip()
    if not key:
        raise ConfigError(f"--set expects key=value, got {text!r}")
    try:
        value = load_yaml_text(raw, f"--set {key}", ConfigError) if raw.strip() else ""
    except ConfigError as exc:
        if "alias" in str(exc):  # a memory bomb, not text
            raise
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
        text = open_text(path, ConfigError, max_bytes=MAX_CONFIG_BYTES).read()
        if re.search(r"^\s*[A-Za-z_][\w.]*\s*=", text, re.M):  # `vslam config`'s lines pasted as they are
            raise ConfigError(f"{path}: write one 'key: value' per line (features.n_features: 1000), not 'key = value'")
        data = load_yaml_text(text, path, ConfigError) or {}  # aliases (memory bombs) refused
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
from dataclasses import dataclass  # noqa: E402

from vslam.backend.config import BackendConfig  # noqa: E402,F401  (re-exported: vslam.config.BackendConfig)
from vslam.features.config import FeatureConfig  # noqa: E402
from vslam.frontend.config import FrontendConfig  # noqa: E402
from vslam.loop.config import LoopConfig  # noqa: E402


@dataclass(frozen=True)
class LocalizerConfig:
    """Map-based localization (``vslam localize``, :class:`vslam.localizer.Localizer`): tracking against a
    fixed map, relocalizing globally when lost."""

    min_inliers: int = param(20, "inliers after the final (local map) refinement to accept a tracked or relocalized pose", bounds="[6, 1000000]")
    min_first_pass_inliers: int = param(12, "inliers of the first (prediction-guided) pass needed to go on to the local-map pass (ORB-SLAM's TrackWithMotionModel: 10)", bounds="[6, 1000000]")
    # The map is fixed and verified by guided matching, so a lower bar than SLAM's (40) recovers sooner.
    reloc_min_inliers: int | None = param(30, "inliers a global relocalization needs (null: loop.relocalization.min_inliers, tuned for SLAM)", bounds="[6, 1000000]")
    search_radius_px: float = param(12.0, "guided-matching radius around the constant-velocity prediction, pixels", bounds="(0, 10000]")
    search_radius_wide_px: float = param(30.0, "retry radius when the first pass finds too few matches, pixels", bounds="(0, 10000]")
    refine_radius_px: float = param(5.0, "radius of the second matching pass at the refined pose, pixels", bounds="(0, 10000]")
    n_near_keyframes: int = param(8, "keyframes nearest to the predicted pose whose points are projected", bounds="[1, 10000]")
    n_covisible: int = param(10, "covisible keyframes of the reference keyframe added to the local map", bounds="[0, 10000]")
    max_view_angle_deg: float = param(70.0, "a nearby keyframe must look within this angle of the predicted view, degrees", bounds="[0, 180]")
    match_ratio: float = param(0.9, "ratio test of the guided matching", bounds="(0, 1]")
    max_descriptor_distance: float = param(64.0, "Hamming bound of the guided matching", bounds="[0, 1000000]")
    max_velocity_m: float = param(0.3, "a constant-velocity step longer than this is reset to zero motion, metres", bounds="[0, 1000000]")
    max_velocity_deg: float = param(30.0, "the same for its rotation, degrees", bounds="[0, 180]")
    max_step_m: float = param(0.1, "a tracked pose farther than this from the prediction is rejected (relocalized instead), metres", bounds="[0, 1000000]")
    max_step_deg: float = param(10.0, "the same for its rotation, degrees", bounds="[0, 180]")
    use_depth: bool = param(True, "RGB-D / stereo depth as extra (virtual right camera) residuals in refinement")
    # The fix the loop verification got: with depth noise growing with z^2 the closed-form pose is centimetres
    # and degrees off, too far for the 8 px guided search (7-Scenes map 0-599, frames 600-999: candidates
    # verified with 20-28 inliers, < 30).
    reloc_refine_ransac: bool = param(True, "global relocalization refines its 3D-3D RANSAC pose on reprojection before guided matching")
    max_point_view_angle_deg: float = param(60.0, "a map point is projected only when seen within this angle of its mean viewing direction, degrees", bounds="[0, 180]")
    check_point_distance: bool = param(True, "a map point is projected only within its scale-invariance distance range (ORB-SLAM's isInFrustum)")
    always_ransac: bool = param(False, "PnP RANSAC on every frame's first matching pass (default: only without a velocity, or after a failed pass)")

    def __post_init__(self) -> None:
        if self.min_inliers < 6 or self.min_first_pass_inliers < 6:
            raise ConfigError(f"localize.min_inliers={self.min_inliers} / min_first_pass_inliers="
                              f"{self.min_first_pass_inliers}: must be >= 6")
        if min(self.search_radius_px, self.search_radius_wide_px, self.refine_radius_px) <= 0:
            raise ConfigError("localize search radii must be > 0 pixels")
        if self.reloc_min_inliers is not None and self.reloc_min_inliers < 6:
            raise ConfigError(f"localize.reloc_min_inliers={self.reloc_min_inliers}: must be >= 6")
        if self.n_near_keyframes < 1 or self.n_covisible < 0:
            raise ConfigError("localize.n_near_keyframes must be >= 1 and n_covisible >= 0")


@dataclass(frozen=True)
class Config:
    """Everything a run is configured by, one section per pipeline stage."""

    features: FeatureConfig = section(FeatureConfig, "feature detection")
    frontend: FrontendConfig = section(FrontendConfig, "tracking: association, motion, keyframes, local map")
    backend: BackendConfig = section(BackendConfig, "local mapping, bundle adjustment, pose graph, EKF")
    loop: LoopConfig = section(LoopConfig, "place recognition, loop closing, relocalization")
    localize: LocalizerConfig = section(LocalizerConfig, "localization in a saved map (vslam localize)")


# features/config.py predates per-field bounds: its ranges are declared here, checked and documented
# exactly as the ``bounds`` of :func:`vslam.param.param`.
_BOUNDS_DECLARED_HERE: dict[type, dict[str, Bounds]] = {FeatureConfig: {name: Bounds.parse(text) for name, text in {
    "n_features": "[1, 100000]", "scale_factor": "(1, 4]", "n_levels": "[1, 32]", "fast_threshold": "[1, 255]",
    "min_fast_threshold": "[0, 255]", "cell_size": "[4, 4096]", "edge_threshold": "[0, 255]",
    "patch_size": "[7, 255]", "sift_contrast_threshold": "(0, 1]", "akaze_threshold": "(0, 1]",
    "brisk_threshold": "[1, 255]", "gftt_quality": "(0, 1]", "gftt_min_distance": "[0, 10000]",
}.items()}}


def with_depth_noise(cfg: Config, sigma_px: float | None) -> Config:
    """``cfg`` with the ``-1`` (auto) of ``backend.local`` / ``backend.global_ba.rgbd_disparity_sigma_px``
    replaced by the depth sensor's disparity std ``sigma_px`` (the dataset's
    ``depth_disparity_sigma_px``), or by 0 (off) when it has none (depth not registered to the colour
    camera); a value set explicitly stays. The run's ``config.yaml`` records the result."""
    backend = cfg.backend
    value = float(sigma_px) if sigma_px else 0.0
    local, glob = backend.local, backend.global_ba
    if local.rgbd_disparity_sigma_px == -1.0:
        local = dataclasses.replace(local, rgbd_disparity_sigma_px=value)
    if glob.rgbd_disparity_sigma_px == -1.0:
        glob = dataclasses.replace(glob, rgbd_disparity_sigma_px=value)
    if local is backend.local and glob is backend.global_ba:
        return cfg
    return dataclasses.replace(cfg, backend=dataclasses.replace(backend, local=local, global_ba=glob))
