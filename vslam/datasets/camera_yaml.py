"""The small camera YAML of image folders and videos (``fx fy cx cy width height [dist baseline
depth_scale fps]``), also accepting ORB-SLAM / OpenCV FileStorage style files."""
from __future__ import annotations

import re
from pathlib import Path

from vslam.datasets.calib_checks import check_camera, check_extras, check_file_size
from vslam.datasets.calib_checks import number as _number, numbers as _numbers
from vslam.errors import CalibrationError
from vslam.geometry.camera import PinholeCamera
from vslam.textfile import load_yaml_text, open_text


def load_yaml(path: Path) -> dict:
    """A camera YAML as a mapping (OpenCV FileStorage directives and tags dropped)."""
    check_file_size(path)  # before parsing: a calibration is a few KB
    text = open_text(path, CalibrationError).read()
    # OpenCV FileStorage YAML: drop the '%YAML:1.0' directive and '!!opencv-matrix' tags
    text = re.sub(r"^%YAML[: ]?1\.0\s*$", "", text, flags=re.M)
    text = text.replace("!!opencv-matrix", "")
    data = load_yaml_text(text, path, CalibrationError)  # aliases (memory bombs) refused
    if not isinstance(data, dict):
        raise CalibrationError(f"{path}: camera file must be a mapping with keys fx, fy, cx, cy, width, height")
    return data


def read_camera_yaml(path: str | Path, image_size: tuple[int, int] | None = None) -> tuple[PinholeCamera, dict]:
    """Read the small camera YAML.

    Keys: ``fx, fy, cx, cy`` (required), ``width, height`` (required unless ``image_size``
    ``(W, H)`` is given), optional ``dist: [k1, k2, p1, p2, k3]``, ``baseline`` (m),
    ``depth_scale`` (PNG units per metre), ``fps``. ORB-SLAM style files (``Camera.fx``,
    ``Camera.k1`` ..., ``Camera.bf``, ``DepthMapFactor``) are accepted too.

    Returns ``(camera, extras)`` with ``extras`` holding ``depth_scale`` and ``fps`` when present.
    """
    path = Path(path)
    if not path.is_file():
        raise CalibrationError(f"{path}: camera file not found")
    data = load_yaml(path)
    orb = any(str(k).startswith("Camera.") for k in data)
    if orb:
        g = {str(k)[len("Camera."):] if str(k).startswith("Camera.") else str(k): v for k, v in data.items()}
        dist = [g.get(k, 0.0) for k in ("k1", "k2", "p1", "p2", "k3")]
        g["dist"] = dist
        if "bf" in g and "fx" in g:
            bf, fx = _number(g["bf"], "Camera.bf", str(path)), _number(g["fx"], "Camera.fx", str(path))
            if fx <= 0:
                raise CalibrationError(f"{path}: focal lengths must be positive (Camera.fx={fx})")
            g["baseline"] = bf / fx
        if "DepthMapFactor" in data:
            g["depth_scale"] = data["DepthMapFactor"]
        data = g

    def number(key: str, required: bool = True, default=None):
        if key not in data or data[key] is None:
            if required:
                raise CalibrationError(
                    f"{path}: camera file lacks '{key}'; it needs fx, fy, cx, cy, width, height "
                    f"(optional dist, baseline, depth_scale, fps)"
                )
            return default
        return _number(data[key], key, str(path))  # a YAML boolean or text is not a number

    fx, fy, cx, cy = (number(k) for k in ("fx", "fy", "cx", "cy"))
    if fx <= 0 or fy <= 0:
        raise CalibrationError(f"{path}: focal lengths must be positive (fx={fx}, fy={fy})")
    need_size = image_size is None
    w = number("width", need_size, None)
    h = number("height", need_size, None)
    if w is None or h is None:
        w, h = image_size  # type: ignore[misc]
    dist_raw = data.get("dist", data.get("distortion", None))
    dist: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0)
    if dist_raw is not None:
        if isinstance(dist_raw, dict) and "data" in dist_raw:
            dist_raw = dist_raw["data"]
        if not isinstance(dist_raw, (list, tuple)):
            raise CalibrationError(f"{path}: 'dist' must be a list [k1, k2, p1, p2, k3], got {dist_raw!r}")
        d = _numbers(dist_raw, "dist", str(path))
        if not 4 <= len(d) <= 5:
            raise CalibrationError(f"{path}: 'dist' needs 4 or 5 numbers [k1, k2, p1, p2, (k3)], got {len(d)}")
        dist = tuple(d + [0.0] * (5 - len(d)))
    baseline = number("baseline", False, None)
    if baseline is not None and baseline <= 0:
        raise CalibrationError(f"{path}: baseline must be positive metres, got {baseline}")
    extras = {}
    ds = number("depth_scale", False, None)
    if ds is not None:
        if ds <= 0:
            raise CalibrationError(f"{path}: depth_scale must be positive (PNG units per metre), got {ds}")
        extras["depth_scale"] = ds
    fps = number("fps", False, None)
    if fps is not None:
        if fps <= 0:
            raise CalibrationError(f"{path}: fps must be positive, got {fps}")
        extras["fps"] = fps
    cam = PinholeCamera(fx, fy, cx, cy, pixels(w, "width", path), pixels(h, "height", path), dist, baseline)
    return check_camera(cam, str(path)), check_extras(extras, str(path))


def pixels(value: float, key: str, path: Path | str) -> int:
    """An image side: a whole number of pixels."""
    if not float(value).is_integer():
        raise CalibrationError(f"{path}: '{key}' = {value!r} is not a whole number of pixels")
    return int(value)
