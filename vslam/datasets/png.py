"""Decoding the PNG files of camera datasets, about 1.7x faster than OpenCV: 8-bit grey, 16-bit
grey (depth) and 8-bit RGB, not interlaced.

A PNG (W3C PNG specification, 3rd edition, sections 5, 7 and 9) is a signature, then chunks:
``IHDR`` (width, height, bit depth, colour type, interlace), the image data split over ``IDAT``
chunks (one zlib stream), ``IEND``. The inflated stream holds each row as a filter-type byte and the
row's bytes, filtered (section 9.2). OpenCV (libpng and zlib) spends 3.4 ms on a 752 x 480 EuRoC
frame, half inflating and half unfiltering. Here ISA-L inflates (python-isal, 0.55 ms) and a
compiled kernel undoes the filters (:mod:`vslam.datasets.png_kernels`, 1.35 ms). The pixels are the
same bytes as OpenCV's: the filters are integer arithmetic, and the tests compare both decoders on
every filter type and on the shared sequences.

:func:`decode` returns None for anything else, and the caller decodes with OpenCV, which also
reports damaged files: other colour types and bit depths, interlaced images, a chunk that could
change what OpenCV returns (``tRNS``, ``eXIf``, ``PLTE``, an unknown one: anything outside
:data:`_HARMLESS` and ``IHDR``, ``IDAT``, ``IEND``), a truncated file, a stream whose checksum or
length is wrong. It also returns None without python-isal (as in the ORB-SLAM3 baseline's
environment, ``benchmarks/BASELINE.md``, which then decodes with OpenCV, like ORB-SLAM3's own
``cv::imread``).
"""
from __future__ import annotations

import struct

import numpy as np

try:
    from isal import isal_zlib as _zlib
except ImportError:  # pragma: no cover - isal is a dependency; without it OpenCV decodes
    _zlib = None

SIGNATURE = b"\x89PNG\r\n\x1a\n"
#: chunks that do not change OpenCV's decoded pixels of the types decoded here: text, time stamp,
#: pixel size, and colour-space and display hints that OpenCV does not apply (each one compared with
#: OpenCV in ``tests/datasets/test_png_kernels.py``)
_HARMLESS = frozenset((b"tEXt", b"zTXt", b"iTXt", b"tIME", b"pHYs", b"gAMA", b"cHRM", b"sRGB", b"iCCP", b"bKGD",
                       b"sBIT"))
#: (colour type, bit depth) -> bytes per pixel, for the types decoded here: grey 8 / 16, RGB 8
_BPP = {(0, 8): 1, (0, 16): 2, (2, 8): 3}


def _chunks(buf: memoryview) -> tuple[bytes, list[memoryview]] | None:
    """``(IHDR data, [IDAT data, ...])`` up to ``IEND``; None for a truncated file or a chunk
    outside the decoded set (module docstring). CRCs are not checked: the zlib stream's own
    Adler-32 checksum covers the image data."""
    i, end = 8, len(buf)
    ihdr, idat = None, []
    while i + 12 <= end:
        (n,) = struct.unpack_from(">I", buf, i)
        kind = bytes(buf[i + 4:i + 8])
        if i + 12 + n > end:
            return None
        data = buf[i + 8:i + 8 + n]
        if kind == b"IEND":
            return (ihdr, idat) if ihdr is not None and idat else None
        if kind == b"IHDR" and ihdr is None and i == 8:
            ihdr = bytes(data)
        elif kind == b"IDAT" and ihdr is not None:
            idat.append(data)
        elif kind not in _HARMLESS:
            return None
        i += 12 + n
    return None


def decode(buf: np.ndarray | bytes, grayscale: bool) -> np.ndarray | None:
    """The image of the PNG file content ``buf`` as ``cv2.imdecode`` gives it (``grayscale``:
    ``IMREAD_GRAYSCALE``, else ``IMREAD_UNCHANGED``): ``(H, W)`` uint8 or uint16, ``(H, W, 3)``
    uint8 BGR; or None where OpenCV must decode it (module docstring)."""
    if _zlib is None or bytes(buf[:8]) != SIGNATURE:
        return None
    from vslam.datasets.png_kernels import unfilter

    found = _chunks(memoryview(buf).cast("B"))
    if found is None:
        return None
    ihdr, idat = found
    if len(ihdr) != 13:
        return None
    w, h, depth, colour, compression, method, interlace = struct.unpack(">IIBBBBB", ihdr)
    bpp = _BPP.get((colour, depth))
    if bpp is None or compression or method or interlace or w == 0 or h == 0:
        return None
    if grayscale and bpp != 1:  # OpenCV converts these: its conversion is not redone here
        return None
    row = w * bpp
    size = h * (row + 1)
    try:
        raw = _zlib.decompress(idat[0] if len(idat) == 1 else b"".join(idat), 15, size)
    except (_zlib.error, ValueError):
        return None
    if len(raw) != size:
        return None
    out = np.empty((h, row), np.uint8)
    if not unfilter(np.frombuffer(raw, np.uint8), out, bpp):
        return None
    if bpp == 1:
        return out
    if bpp == 2:  # big-endian samples (section 7.1)
        return out.view(">u2").astype(np.uint16)
    return np.ascontiguousarray(out.reshape(h, w, 3)[:, :, ::-1])  # RGB -> OpenCV's BGR
