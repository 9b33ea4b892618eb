"""Files and image decoding of the dataset readers: path checks, :func:`load_image` /
:func:`load_depth` with a :class:`DatasetError` that names the file (missing, unreadable,
truncated, oversized from its header) instead of OpenCV's silent ``None``, and image listings."""
from __future__ import annotations

import re
from pathlib import Path
from typing import Sequence

import numpy as np

from vslam.datasets import png
from vslam.errors import DatasetError

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
    if data[:8] == png.SIGNATURE and len(data) >= 24 and data[12:16] == b"IHDR":
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


def _decode(buf: np.ndarray, grayscale: bool) -> np.ndarray | None:
    """``cv2.imdecode`` with ``IMREAD_GRAYSCALE`` / ``IMREAD_UNCHANGED``: the common PNGs by
    :mod:`vslam.datasets.png` (the same pixels, faster), everything else by OpenCV; None when
    neither can decode it."""
    import cv2

    img = png.decode(buf, grayscale)
    if img is not None:
        return img
    return cv2.imdecode(buf, cv2.IMREAD_GRAYSCALE if grayscale else cv2.IMREAD_UNCHANGED)


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
    img = _decode(buf, grayscale)
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
        shape: expected ``(H, W)`` (the colour image's).
        invalid: raw values meaning "no measurement" (7-Scenes uses 0 and 65535).

    Raises:
        CorruptFrameError: the file is missing, empty, cannot be decoded, is not single-channel
            16-bit (an 8-bit, colour or float32 TIFF frame) or has the wrong size; the dataset
            iterator skips and counts such a frame (fatal only for the first frame or too many).
    """
    path = Path(path)
    buf = _read_bytes(path, "depth")
    _check_header(path, buf, "depth")
    raw = _decode(buf, grayscale=False)
    if raw is None:
        raise CorruptFrameError(f"{path}: depth image cannot be decoded (truncated or not a PNG); re-extract it")
    if raw.ndim != 2 or raw.dtype != np.uint16:  # one such frame is skipped like a corrupt one
        raise CorruptFrameError(
            f"{path}: depth must be a single-channel 16-bit PNG ({scale:g} units per metre), got "
            f"{raw.dtype} with shape {raw.shape}; 8-bit or colour depth cannot hold metric depth"
        )
    if shape is not None and raw.shape != tuple(shape):
        raise CorruptFrameError(
            f"{path}: depth image is {raw.shape[1]}x{raw.shape[0]} but the colour image is "
            f"{shape[1]}x{shape[0]}; depth must be registered to and the same size as the colour image"
        )
    # 0 / scale is 0 already; one other invalid value (7-Scenes' 65535): one compiled pass
    bad = [int(v) for v in invalid if v != 0]
    if len(bad) <= 1 and raw.flags.c_contiguous:
        from vslam.datasets.depth_kernels import scale_depth

        depth = np.empty(raw.shape, np.float32)
        scale_depth(raw, np.float32(scale), bad[0] if bad else -1, depth)
        return depth
    depth = raw.astype(np.float32) / np.float32(scale)
    for v in bad:
        depth[raw == v] = 0.0
    return depth


def list_images(folder: Path) -> list[Path]:
    """Image files in ``folder`` sorted by name with numbers compared numerically."""
    files = [p for p in folder.iterdir() if p.suffix.lower() in IMAGE_EXTENSIONS and p.is_file()]
    return sorted(files, key=lambda p: natural_key(p.name))


def natural_key(name: str) -> list:
    return [int(s) if s.isdigit() else s for s in re.split(r"(\d+)", name)]
