"""The numbers of a camera calibration, checked where they enter (every calibration reader calls
these), so a wrong value is one line naming the file and key instead of a silent nonsense run or a
failure deep inside bundle adjustment.

Limits (README, "Your own camera"):

* the file: at most :data:`MAX_CALIBRATION_BYTES` (1 MB; a calibration is a few KB) read, YAML
  aliases (``&a`` / ``*a``, the "billion laughs" memory bomb) refused;
* a number must be written as one: a YAML boolean (``fx: yes``) or text (``fx: "500"``) is refused;
* ``width`` / ``height``: whole numbers of pixels, 1 .. :data:`MAX_IMAGE_SIDE`;
* ``fx`` / ``fy``: finite, positive, and between :data:`FOCAL_RANGE` = 0.05 and 100 times the image
  width (a 640-pixel image: 32 to 64000 px, i.e. fields of view from about 172 down to 0.6 degrees);
* ``cx`` / ``cy``: inside the image (``0 <= cx <= width``, ``0 <= cy <= height``);
* distortion coefficients: finite, ``|k| <=`` :data:`MAX_DISTORTION` (1000; real lenses have
  ``|k| < 10``, and the undistortion cannot invert polynomials far beyond that);
* ``depth_scale``: finite, in :data:`DEPTH_SCALE_RANGE` (0.001 to 1e6 depth units per metre; TUM
  5000, 7-Scenes 1000, 1 for depth in metres); ``baseline``: finite, in (0, 1000] m; ``fps``:
  finite, in (0, 10000].
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from vslam.errors import CalibrationError
from vslam.geometry.camera import PinholeCamera

MAX_CALIBRATION_BYTES = 1_000_000
MAX_IMAGE_SIDE = 65536
FOCAL_RANGE = (0.05, 100.0)
MAX_DISTORTION = 1e3
DEPTH_SCALE_RANGE = (1e-3, 1e6)
MAX_BASELINE_M = 1e3
MAX_FPS = 1e4


def check_file_size(path: Path) -> None:
    """Refuse a calibration file over :data:`MAX_CALIBRATION_BYTES` before it is parsed."""
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise CalibrationError(f"{path}: cannot read ({exc.strerror or exc})") from None
    if size > MAX_CALIBRATION_BYTES:
        raise CalibrationError(f"{path}: {size} bytes is not a calibration file (those are a few KB; at most "
                               f"{MAX_CALIBRATION_BYTES} bytes are read); pass the right file")


def is_number(value: object) -> bool:
    """A number as YAML / JSON / OpenCV give one: int or float, not a boolean, not text."""
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_))


def not_a_number(where: str, key: str, value: object) -> CalibrationError:
    kind = "a YAML boolean" if isinstance(value, (bool, np.bool_)) else (
        "text" if isinstance(value, str) else type(value).__name__)
    return CalibrationError(f"{where}: '{key}' = {value!r} is not a number ({kind}); write it as a number")


def number(value: object, key: str, where: str) -> float:
    """``value`` as a finite float, or :class:`CalibrationError` naming ``where`` and ``key``."""
    if not is_number(value):
        raise not_a_number(where, key, value)
    x = float(value)  # type: ignore[arg-type]
    if not math.isfinite(x):
        raise CalibrationError(f"{where}: '{key}' = {value!r} is not finite")
    return x


def numbers(values: object, key: str, where: str) -> list[float]:
    """A (nested) list of numbers, flattened; every element checked by :func:`number`."""
    out: list[float] = []

    def walk(v: object) -> None:
        if isinstance(v, (list, tuple, np.ndarray)):
            for item in v:
                walk(item)
        else:
            out.append(number(v, key, where))

    walk(values)
    return out


def _in_range(value: float | None, key: str, where: str, low: float, high: float, unit: str,
              low_open: bool = False) -> None:
    if value is None:
        return
    if not math.isfinite(value) or value > high or value < low or (low_open and value == low):
        side = f"above 0 and at most {high:g}" if low_open and low == 0 else f"between {low:g} and {high:g}"
        raise CalibrationError(f"{where}: '{key}' = {value!r} is out of range; it must be {side} {unit}".rstrip())


def check_camera(cam: PinholeCamera, where: str, prefix: str = "") -> PinholeCamera:
    """Refuse a camera whose numbers cannot be a real calibration (see the module docstring);
    ``prefix`` names the keys as the file does (``cam0/``)."""
    w, h = cam.width, cam.height
    for key, v in (("width", w), ("height", h)):
        if not 1 <= v <= MAX_IMAGE_SIDE:
            raise CalibrationError(f"{where}: '{prefix}{key}' = {v} pixels is not an image size "
                                   f"(1 .. {MAX_IMAGE_SIDE})")
    lo, hi = FOCAL_RANGE
    for key, f in (("fx", cam.fx), ("fy", cam.fy)):
        if not math.isfinite(f) or f <= 0:
            raise CalibrationError(f"{where}: '{prefix}{key}' = {f!r}: focal lengths must be positive and finite")
        if not lo * w <= f <= hi * w:
            raise CalibrationError(f"{where}: '{prefix}{key}' = {f:g} px is implausible for an image {w} px wide "
                                   f"(expected {lo:g} to {hi:g} x the width: {lo * w:g} to {hi * w:g} px)")
    for key, c, size in (("cx", cam.cx, w), ("cy", cam.cy, h)):
        if not (math.isfinite(c) and 0.0 <= c <= size):
            raise CalibrationError(f"{where}: '{prefix}{key}' = {c!r}: the principal point must lie inside the "
                                   f"{w}x{h} image (0 .. {size})")
    for i, k in enumerate(cam.dist):
        if not math.isfinite(k) or abs(k) > MAX_DISTORTION:
            raise CalibrationError(f"{where}: '{prefix}distortion[{i}]' = {k!r} is not a lens distortion "
                                   f"(finite, |k| <= {MAX_DISTORTION:g})")
    _in_range(cam.baseline, f"{prefix}baseline", where, 0.0, MAX_BASELINE_M, "m", low_open=True)
    return cam


def check_extras(extras: dict, where: str) -> dict:
    """Refuse a ``depth_scale`` or ``fps`` out of range (see the module docstring)."""
    _in_range(extras.get("depth_scale"), "depth_scale", where, *DEPTH_SCALE_RANGE, "depth units per metre")
    _in_range(extras.get("fps"), "fps", where, 0.0, MAX_FPS, "frames per second", low_open=True)
    return extras
