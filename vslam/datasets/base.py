"""The :class:`Dataset` base class every reader derives from, and the helpers they share.

Shared pieces:

* :func:`load_image` / :func:`load_depth`: decode one file with a :class:`DatasetError` that names
  it (missing, unreadable, truncated, wrong size) instead of OpenCV's silent ``None``.
* :func:`read_timestamped_list`: TUM-style ``timestamp filename`` lists (``rgb.txt``), checked sorted.
* :func:`associate`: TUM ``associate.py`` matching of two timestamp lists (greedy by |dt|).
* :func:`interpolate_poses`: ground truth at arbitrary times (SLERP + linear translation).
* :func:`read_camera_yaml`: the small camera YAML (``fx fy cx cy width height [dist baseline
  depth_scale fps]``), also accepting ORB-SLAM style ``Camera.fx`` keys.

Iteration policy (see :meth:`Dataset.frames`): opening a dataset only lists files; images are
decoded lazily one frame at a time. A frame whose image cannot be decoded is skipped with a logging
warning and counted in :attr:`Dataset.skipped`, unless it is the first frame requested or more
than :attr:`Dataset.max_skip_fraction` of the requested range fails, which raises.
"""
from __future__ import annotations

import logging
import re
from pathlib import Path
from typing import Iterator, Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from vslam.datasets.frame import Frame
from vslam.errors import CalibrationError, DatasetError
from vslam.textfile import open_text
from vslam.trajectory import Trajectory
from vslam.geometry.camera import PinholeCamera

log = logging.getLogger(__name__)

SENSORS = ("mono", "stereo", "rgbd")
IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm", ".webp")


class CorruptFrameError(DatasetError):
    """One frame's file cannot be decoded (the iterator may skip it)."""


# ----------------------------------------------------------------------------------------------
# Files
# ----------------------------------------------------------------------------------------------
def require_dir(path: str | Path, what: str) -> Path:
    path = Path(path)
    if not path.exists():
        raise DatasetError(f"{path}: {what} not found; check the path")
    if not path.is_dir():
        raise DatasetError(f"{path}: {what} must be a folder, this is a file")
    return path


def require_file(path: str | Path, what: str) -> Path:
    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"{path}: {what} not found; the sequence is incomplete or the path is wrong")
    return path


def _read_bytes(path: Path, what: str) -> np.ndarray:
    try:
        with open(path, "rb") as fh:
            data = fh.read()
    except FileNotFoundError:
        raise CorruptFrameError(f"{path}: {what} file is missing") from None
    except OSError as exc:
        raise CorruptFrameError(f"{path}: cannot read {what} ({exc.strerror})") from None
    if not data:
        raise CorruptFrameError(f"{path}: {what} file is empty; re-extract or remove it from the list")
    return np.frombuffer(data, dtype=np.uint8)


#: images above this many pixels are refused from their header, before decoding (a 30000x30000 PNG
#: of a few hundred KB would otherwise take gigabytes)
MAX_IMAGE_PIXELS = 1 << 26  # 67 megapixels, e.g. 8192 x 8192


def image_header_size(buf: bytes | np.ndarray) -> tuple[int, int] | None:
    """``(width, height)`` from a PNG (IHDR) or JPEG (SOFn) header, without decoding; None for
    other formats or a header that cannot be parsed."""
    data = bytes(buf[:1 << 16]) if not isinstance(buf, bytes) else buf[:1 << 16]
    if data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) >= 24 and data[12:16] == b"IHDR":
        return int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")
    if data[:2] == b"\xff\xd8":
        i = 2
        while i + 9 <= len(data):
            if data[i] != 0xFF:
                return None
            marker = data[i + 1]
            if marker in (0xD8, 0x01) or 0xD0 <= marker <= 0xD7:
                i += 2
                continue
            length = int.from_bytes(data[i + 2:i + 4], "big")
            if 0xC0 <= marker <= 0xCF and marker not in (0xC4, 0xC8, 0xCC):
                return int.from_bytes(data[i + 7:i + 9], "big"), int.from_bytes(data[i + 5:i + 7], "big")
            i += 2 + length
    return None


def _check_header(path: Path, buf: np.ndarray, what: str) -> None:
    """Refuse an image whose header announces more than :data:`MAX_IMAGE_PIXELS` (or 0) pixels."""
    size = image_header_size(buf)
    if size is not None:
        w, h = size
        if w <= 0 or h <= 0 or w * h > MAX_IMAGE_PIXELS:
            raise CorruptFrameError(f"{path}: {what} header says {w}x{h} pixels, not a plausible camera "
                                    f"image (at most {MAX_IMAGE_PIXELS} pixels); replace the file")


def _check_not_truncated(path: Path, buf: np.ndarray, what: str) -> None:
    """JPEG decoders fill a truncated file with grey silently; require the EOI marker (FF D9)."""
    if len(buf) >= 2 and buf[0] == 0xFF and buf[1] == 0xD8:
        tail = buf[-64:].tobytes()
        if b"\xff\xd9" not in tail:
            raise CorruptFrameError(f"{path}: {what} JPEG is truncated (no end-of-image marker); re-extract it")


def load_image(path: str | Path, grayscale: bool = False) -> np.ndarray:
    """Decode an 8-bit image as stored (``(H, W)`` gray or ``(H, W, 3)`` BGR), or raise.

    Raises:
        CorruptFrameError: the file is missing, empty, truncated or not an image.
    """
    import cv2

    path = Path(path)
    buf = _read_bytes(path, "image")
    _check_header(path, buf, "image")
    _check_not_truncated(path, buf, "image")
    flag = cv2.IMREAD_GRAYSCALE if grayscale else cv2.IMREAD_UNCHANGED
    img = cv2.imdecode(buf, flag)
    if img is None:
        raise CorruptFrameError(f"{path}: image cannot be decoded (truncated or not an image); re-extract it")
    if img.dtype != np.uint8:
        if img.dtype == np.uint16:
            img = (img >> 8).astype(np.uint8)
        else:
            raise CorruptFrameError(f"{path}: unsupported image type {img.dtype}; store 8-bit images")
    if img.ndim == 3:
        if img.shape[2] == 4:
            img = cv2.cvtColor(img, cv2.COLOR_BGRA2BGR)
        elif img.shape[2] == 1:
            img = img[:, :, 0]
    return img


def load_depth(
    path: str | Path, scale: float, shape: tuple[int, int] | None = None, invalid: Sequence[int] = (0,)
) -> np.ndarray:
    """Decode a 16-bit depth PNG to float32 metres (``value / scale``), 0 where ``invalid``.

    Args:
        scale: PNG units per metre (TUM 5000, 7-Scenes 1000).
        shape: expected ``(H, W)`` (the colour image's); a mismatch raises :class:`DatasetError`.
        invalid: raw values meaning "no measurement" (7-Scenes uses 0 and 65535).
    """
    import cv2

    path = Path(path)
    buf = _read_bytes(path, "depth")
    _check_header(path, buf, "depth")
    raw = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED)
    if raw is None:
        raise CorruptFrameError(f"{path}: depth image cannot be decoded (truncated or not a PNG); re-extract it")
    if raw.ndim != 2 or raw.dtype != np.uint16:
        raise DatasetError(
            f"{path}: depth must be a single-channel 16-bit PNG ({scale:g} units per metre), got "
            f"{raw.dtype} with shape {raw.shape}; 8-bit or colour depth cannot hold metric depth"
        )
    if shape is not None and raw.shape != tuple(shape):
        raise CorruptFrameError(
            f"{path}: depth image is {raw.shape[1]}x{raw.shape[0]} but the colour image is "
            f"{shape[1]}x{shape[0]}; depth must be registered to and the same size as the colour image"
        )
    depth = raw.astype(np.float32) / np.float32(scale)
    for v in invalid:
        if v != 0:
            depth[raw == v] = 0.0
    return depth


def list_images(folder: Path) -> list[Path]:
    """Image files in ``folder`` sorted by name with numbers compared numerically."""
    files = [p for p in folder.iterdir() if p.suffix.lower() in IMAGE_EXTENSIONS and p.is_file()]
    return sorted(files, key=lambda p: natural_key(p.name))


def natural_key(name: str) -> list:
    return [int(s) if s.isdigit() else s for s in re.split(r"(\d+)", name)]


def check_timestamps(ts: np.ndarray, path: str | Path) -> None:
    """Raise unless ``ts`` is strictly increasing (names the first offending line/position)."""
    ts = np.asarray(ts, dtype=float)
    if not np.all(np.isfinite(ts)):
        raise DatasetError(f"{path}: timestamp {int(np.argmax(~np.isfinite(ts))) + 1} is not a finite number")
    d = np.diff(ts)
    if np.any(d == 0):
        i = int(np.argmax(d == 0))
        raise DatasetError(f"{path}: duplicate timestamp {ts[i]!r} (entries {i + 1} and {i + 2}); remove one")
    if np.any(d < 0):
        i = int(np.argmax(d < 0))
        raise DatasetError(
            f"{path}: timestamps are not sorted (entry {i + 2}, {ts[i + 1]!r}, is before {ts[i]!r}); sort the file"
        )


def read_timestamped_list(path: str | Path, what: str, min_columns: int = 2) -> tuple[np.ndarray, list[list[str]]]:
    """Read a TUM-style list (``timestamp field ...`` per line, ``#`` comments).

    Returns ``(timestamps (N,), rows)`` where ``rows[i]`` are the remaining fields of line i.
    Timestamps are kept as parsed (not sorted); use :func:`check_timestamps`.
    """
    path = require_file(path, what)
    ts: list[float] = []
    rows: list[list[str]] = []
    with open_text(path, DatasetError) as fh:
        for lineno, line in enumerate(fh, 1):
            line = line.strip()
            if not line or line.startswith("#"):
                continue
            parts = line.replace(",", " ").split()
            if len(parts) < min_columns:
                raise DatasetError(
                    f"{path}:{lineno}: expected {min_columns} columns (timestamp filename ...), got {line[:80]!r}"
                )
            try:
                ts.append(float(parts[0]))
            except ValueError:
                raise DatasetError(f"{path}:{lineno}: timestamp {parts[0]!r} is not a number") from None
            rows.append(parts[1:])
    if not ts:
        raise DatasetError(f"{path}: the {what} has no entries")
    return np.array(ts, dtype=float), rows


# ----------------------------------------------------------------------------------------------
# Timestamps and ground truth
# ----------------------------------------------------------------------------------------------
def associate(
    t_first: np.ndarray, t_second: np.ndarray, offset: float = 0.0, max_difference: float = 0.02
) -> np.ndarray:
    """Match two timestamp lists like TUM's ``associate.py``.

    Every candidate pair with ``|t1 - (t2 + offset)| < max_difference`` is sorted by that
    difference and accepted greedily, each timestamp used at most once (Sturm et al., IROS 2012,
    ``associate.py``). Returns ``(M, 2)`` index pairs sorted by the first index.
    """
    t1 = np.asarray(t_first, dtype=float)
    t2 = np.asarray(t_second, dtype=float) + offset
    order2 = np.argsort(t2, kind="stable")
    t2s = t2[order2]
    lo = np.searchsorted(t2s, t1 - max_difference, side="left")
    hi = np.searchsorted(t2s, t1 + max_difference, side="right")
    counts = hi - lo
    if counts.sum() == 0:
        return np.zeros((0, 2), dtype=int)
    i1 = np.repeat(np.arange(len(t1)), counts)
    starts = np.repeat(lo - np.concatenate([[0], np.cumsum(counts)[:-1]]), counts)
    j_sorted = starts + np.arange(counts.sum())
    i2 = order2[j_sorted]
    diff = np.abs(t1[i1] - t2[i2])
    keep = diff < max_difference
    i1, i2, diff = i1[keep], i2[keep], diff[keep]
    used1 = np.zeros(len(t1), dtype=bool)
    used2 = np.zeros(len(t2), dtype=bool)
    pairs = []
    for k in np.argsort(diff, kind="stable"):
        a, b = i1[k], i2[k]
        if not used1[a] and not used2[b]:
            used1[a] = used2[b] = True
            pairs.append((a, b))
    out = np.array(sorted(pairs), dtype=int).reshape(-1, 2)
    return out


def interpolate_poses(
    gt: Trajectory, t_query: np.ndarray, max_gap: float = 0.1, exact_tol: float = 1e-5
) -> tuple[np.ndarray, np.ndarray]:
    """Ground-truth poses at ``t_query`` (SLERP rotation, linear translation between neighbours).

    A query within ``exact_tol`` seconds of a GT sample takes that sample; otherwise it needs GT
    samples on both sides no more than ``max_gap`` seconds apart. Returns
    ``(T_world_cam (N, 4, 4), valid (N,) bool)``; invalid rows are NaN.
    """
    t_query = np.asarray(t_query, dtype=float).reshape(-1)
    n = len(t_query)
    T = np.full((n, 4, 4), np.nan)
    valid = np.zeros(n, dtype=bool)
    tg = gt.timestamps
    if len(tg) == 0 or n == 0:
        return T, valid
    idx = np.searchsorted(tg, t_query)  # tg[idx-1] < t <= tg[idx]
    # exact matches (nearest neighbour within exact_tol)
    left = np.clip(idx - 1, 0, len(tg) - 1)
    right = np.clip(idx, 0, len(tg) - 1)
    d_left = np.abs(t_query - tg[left])
    d_right = np.abs(t_query - tg[right])
    nearest = np.where(d_left <= d_right, left, right)
    exact = np.minimum(d_left, d_right) <= exact_tol
    T[exact] = gt.T_world_cam[nearest[exact]]
    valid[exact] = True
    # interpolation between neighbours
    inside = (~exact) & (idx > 0) & (idx < len(tg))
    if np.any(inside):
        i1 = idx[inside]
        i0 = i1 - 1
        gap = tg[i1] - tg[i0]
        ok = gap <= max_gap
        q_idx = np.flatnonzero(inside)[ok]
        i0, i1 = i0[ok], i1[ok]
        if len(q_idx):
            alpha = (t_query[q_idx] - tg[i0]) / (tg[i1] - tg[i0])
            R0 = Rotation.from_matrix(gt.T_world_cam[i0, :3, :3])
            R1 = Rotation.from_matrix(gt.T_world_cam[i1, :3, :3])
            delta = (R0.inv() * R1).as_rotvec()
            R = R0 * Rotation.from_rotvec(alpha[:, None] * delta)
            Ti = np.tile(np.eye(4), (len(q_idx), 1, 1))
            Ti[:, :3, :3] = R.as_matrix()
            p0 = gt.T_world_cam[i0, :3, 3]
            p1 = gt.T_world_cam[i1, :3, 3]
            Ti[:, :3, 3] = p0 + alpha[:, None] * (p1 - p0)
            T[q_idx] = Ti
            valid[q_idx] = True
    return T, valid


# ----------------------------------------------------------------------------------------------
# Camera YAML
# ----------------------------------------------------------------------------------------------
def _load_yaml(path: Path) -> dict:
    import yaml

    text = open_text(path, CalibrationError).read()
    # OpenCV FileStorage YAML: drop the '%YAML:1.0' directive and '!!opencv-matrix' tags
    text = re.sub(r"^%YAML[: ]?1\.0\s*$", "", text, flags=re.M)
    text = text.replace("!!opencv-matrix", "")
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise CalibrationError(f"{path}: camera file is not valid YAML ({exc.__class__.__name__}); fix its syntax") from None
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
    data = _load_yaml(path)
    orb = any(str(k).startswith("Camera.") for k in data)
    if orb:
        g = {str(k)[len("Camera."):] if str(k).startswith("Camera.") else str(k): v for k, v in data.items()}
        dist = [g.get(k, 0.0) for k in ("k1", "k2", "p1", "p2", "k3")]
        g["dist"] = dist
        if "bf" in g and "fx" in g:
            try:
                g["baseline"] = float(g["bf"]) / float(g["fx"])
            except (TypeError, ValueError, ZeroDivisionError):
                raise CalibrationError(f"{path}: Camera.bf / Camera.fx is not a number") from None
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
        try:
            v = float(data[key])
        except (TypeError, ValueError):
            raise CalibrationError(f"{path}: camera '{key}' = {data[key]!r} is not a number") from None
        if not np.isfinite(v):
            raise CalibrationError(f"{path}: camera '{key}' = {data[key]!r} is not finite")
        return v

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
        try:
            d = [float(x) for x in dist_raw]
        except (TypeError, ValueError):
            raise CalibrationError(f"{path}: 'dist' must be a list [k1, k2, p1, p2, k3], got {dist_raw!r}") from None
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
    cam = PinholeCamera(fx, fy, cx, cy, int(w), int(h), dist, baseline)
    return cam, extras


# ----------------------------------------------------------------------------------------------
# Dataset
# ----------------------------------------------------------------------------------------------
class Dataset:
    """A sequence of :class:`Frame` records read lazily from disk.

    Subclasses set ``name``, ``kind``, ``camera``, ``sensors``, ``sensor``, ``frame_rate``,
    ``root`` and ``_timestamps`` in ``__init__`` and implement :meth:`_load` (decode frame ``i``)
    and :meth:`_gt_poses` (ground truth at every frame, NaN where unknown).
    """

    name: str = ""
    kind: str = ""
    camera: PinholeCamera
    sensors: tuple[str, ...] = ("mono",)
    sensor: str = "mono"
    frame_rate: float = 30.0
    root: Path
    #: iteration raises once more than this fraction of the requested frames failed to decode
    max_skip_fraction: float = 0.1

    def __init__(self) -> None:
        self._skipped: set[int] = set()
        self._timestamps = np.zeros(0)
        self._gt_cache: tuple[np.ndarray, np.ndarray] | None = None

    @property
    def skipped(self) -> int:
        """How many distinct frames were skipped so far because they failed to decode."""
        return len(self._skipped)

    # -- sensors --------------------------------------------------------------------------------
    def _select_sensor(self, sensor: str | None, default: str, missing: dict[str, str] | None = None) -> str:
        """Validate ``sensor`` against :attr:`sensors`; ``missing`` explains why one is absent."""
        if sensor is None:
            return default
        sensor = sensor.lower()
        if sensor not in SENSORS:
            raise DatasetError(f"unknown sensor {sensor!r}; use one of {', '.join(SENSORS)}")
        if sensor not in self.sensors:
            why = (missing or {}).get(sensor, "")
            raise DatasetError(
                f"{self.root}: sensor '{sensor}' is not available for this {self.kind} sequence"
                f"{': ' + why if why else ''} (available: {', '.join(self.sensors)})"
            )
        return sensor

    # -- sequence protocol ---------------------------------------------------------------------
    @property
    def timestamps(self) -> np.ndarray:
        """Frame timestamps in seconds ``(N,)``."""
        return self._timestamps

    def __len__(self) -> int:
        return len(self._timestamps)

    def __getitem__(self, i: int) -> Frame:
        n = len(self)
        if not isinstance(i, (int, np.integer)):
            raise TypeError("dataset indices must be integers; use frames(start, stop) for ranges")
        if i < 0:
            i += n
        if not 0 <= i < n:
            raise IndexError(f"frame {i} out of range (the sequence has {n} frames)")
        return self._load(int(i))

    def __iter__(self) -> Iterator[Frame]:
        return self.frames()

    def frames(self, start: int = 0, stop: int | None = None) -> Iterator[Frame]:
        """Yield frames ``start .. stop-1``, decoding one at a time (memory stays flat).

        Frames that fail to decode are skipped with a warning and counted in :attr:`skipped`;
        the first requested frame failing, or more than :attr:`max_skip_fraction` of the range,
        raises :class:`DatasetError`.
        """
        n = len(self)
        stop = n if stop is None else min(stop, n)
        start = max(0, start)
        total = max(stop - start, 0)
        failed = 0
        for i in range(start, stop):
            try:
                frame = self._load(i)
            except CorruptFrameError as exc:
                if i == start:
                    raise DatasetError(f"{exc} (the first frame must be readable)") from None
                failed += 1
                self._skipped.add(i)
                if failed > max(1, self.max_skip_fraction * total):
                    raise DatasetError(
                        f"{exc}; {failed} of {total} frames failed to decode, more than "
                        f"{self.max_skip_fraction:.0%}: the sequence is damaged, re-extract it"
                    ) from None
                log.warning("skipping frame %d: %s", i, exc)
                continue
            yield frame

    def _check_size(self, image: np.ndarray, path: Path) -> None:
        """Raise when an image does not have the calibrated size."""
        h, w = image.shape[:2]
        if (w, h) != (self.camera.width, self.camera.height):
            raise CorruptFrameError(
                f"{path}: image is {w}x{h} but the calibration says {self.camera.width}x{self.camera.height}; "
                f"fix the calibration or the image"
            )

    def _load(self, i: int) -> Frame:  # pragma: no cover - abstract
        raise NotImplementedError

    # -- ground truth --------------------------------------------------------------------------
    def _gt_poses(self) -> tuple[np.ndarray, np.ndarray] | None:
        """``(T_world_cam (N, 4, 4), valid (N,))`` at the frame timestamps, or None."""
        return None

    def _gt(self) -> tuple[np.ndarray, np.ndarray] | None:
        if self._gt_cache is None:
            res = self._gt_poses()
            if res is None:
                return None
            self._gt_cache = res
        return self._gt_cache

    def gt_pose(self, i: int) -> np.ndarray | None:
        """Ground-truth ``T_world_cam`` of frame ``i`` or None."""
        gt = self._gt()
        if gt is None or not gt[1][i]:
            return None
        return gt[0][i].copy()

    def ground_truth(self) -> Trajectory | None:
        """Ground truth at the frame timestamps (frames GT covers only), or None without GT.

        Poses are of the camera whose images the frames carry (for rectified stereo: the
        rectified left camera).
        """
        gt = self._gt()
        if gt is None or not np.any(gt[1]):
            return None
        T, valid = gt
        return Trajectory(self._timestamps[valid], T[valid])

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}(name={self.name!r}, frames={len(self)}, sensor={self.sensor!r}, "
            f"sensors={self.sensors}, frame_rate={self.frame_rate:g})"
        )
