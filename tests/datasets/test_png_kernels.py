"""The PNG decoder (:mod:`vslam.datasets.png`, its kernel :mod:`vslam.datasets.png_kernels`) against
OpenCV's, byte for byte: every filter type on every decoded colour type, libpng's own files, the
shared sequences; and the files it leaves to OpenCV.

The filters are integer arithmetic (PNG specification section 9.2), so the comparisons are exact on
any CPU. The files are written here: a small PNG encoder (:func:`_png`) that filters each row with
a chosen filter type, so that all five are exercised (libpng picks them adaptively).
"""
from __future__ import annotations

import struct
import zlib

import cv2
import numpy as np
import pytest

from vslam.datasets import png
from vslam.datasets.base import CorruptFrameError, load_image
from vslam.datasets.images import load_depth
from vslam.datasets.png_kernels import unfilter


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def _paeth(a: int, b: int, c: int) -> int:
    p = a + b - c
    pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
    return a if pa <= pb and pa <= pc else (b if pb <= pc else c)


def _filtered(rows: np.ndarray, bpp: int, filters: list[int]) -> bytes:
    """The PNG image data before compression: each row's filter type and ``Filt(x) = Orig(x) -
    Pred(x) mod 256`` (section 9.2), written out plainly from the original bytes."""
    out = bytearray()
    prev = np.zeros(rows.shape[1], np.int64)
    for row, f in zip(rows.astype(np.int64), filters):
        out.append(f)
        for x in range(len(row)):
            a = int(row[x - bpp]) if x >= bpp else 0
            b = int(prev[x])
            c = int(prev[x - bpp]) if x >= bpp else 0
            pred = (0, a, b, (a + b) // 2, _paeth(a, b, c))[f]
            out.append((int(row[x]) - pred) % 256)
        prev = row
    return bytes(out)


def _png(img: np.ndarray, filters: list[int] | None = None, extra: tuple[tuple[bytes, bytes], ...] = (),
         idat_parts: int = 1, interlace: int = 0) -> bytes:
    """A PNG of ``img``: ``(H, W)`` uint8 / uint16 grey or ``(H, W, 3)`` uint8 RGB, rows filtered by
    ``filters`` (default: the types 0-4 in turn), ``extra`` chunks before the image data, the
    compressed stream split over ``idat_parts`` IDAT chunks."""
    h, w = img.shape[:2]
    colour = 2 if img.ndim == 3 else 0
    depth = 16 if img.dtype == np.uint16 else 8
    bpp = (3 if colour == 2 else 1) * depth // 8
    rows = (img.astype(">u2") if depth == 16 else img).reshape(h, -1).view(np.uint8).reshape(h, w * bpp)
    filters = [y % 5 for y in range(h)] if filters is None else filters
    stream = zlib.compress(_filtered(rows, bpp, filters), 6)
    cut = np.linspace(0, len(stream), idat_parts + 1).astype(int)
    return (png.SIGNATURE + _chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, depth, colour, 0, 0, interlace))
            + b"".join(_chunk(k, d) for k, d in extra)
            + b"".join(_chunk(b"IDAT", stream[a:b]) for a, b in zip(cut[:-1], cut[1:])) + _chunk(b"IEND", b""))


def _opencv(data: bytes, grayscale: bool) -> np.ndarray:
    return cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_GRAYSCALE if grayscale else cv2.IMREAD_UNCHANGED)


def _images(rng) -> dict[str, np.ndarray]:
    """Random images of the three decoded kinds, with smooth parts (small filtered values) and noise
    (every byte value, the wrap-around of the modulo)."""
    h, w = 11, 17
    ramp = (np.add.outer(np.arange(h), np.arange(w)) * 9).astype(np.int64)
    return {
        "grey8": ((ramp + rng.integers(0, 40, (h, w))) % 256).astype(np.uint8),
        "grey16": (ramp * 257 + rng.integers(0, 65536, (h, w))).astype(np.uint16),
        "rgb8": rng.integers(0, 256, (h, w, 3)).astype(np.uint8),
    }


@pytest.mark.parametrize("kind", ["grey8", "grey16", "rgb8"])
@pytest.mark.parametrize("filters", ["each", "mixed", 0, 1, 2, 3, 4])
def test_every_filter_type_decodes_as_opencv(kind, filters):
    rng = np.random.default_rng(7)
    img = _images(rng)[kind]
    h = img.shape[0]
    rows = {"each": None, "mixed": rng.integers(0, 5, h).tolist()}.get(filters, [filters] * h)
    data = _png(img, rows, idat_parts=3)
    ours = png.decode(np.frombuffer(data, np.uint8), grayscale=False)
    theirs = _opencv(data, grayscale=False)
    assert ours is not None and ours.dtype == theirs.dtype and ours.shape == theirs.shape
    np.testing.assert_array_equal(ours, theirs)
    np.testing.assert_array_equal(ours, img[:, :, ::-1] if kind == "rgb8" else img)  # BGR as OpenCV
    if kind == "grey8":
        np.testing.assert_array_equal(png.decode(data, grayscale=True), _opencv(data, grayscale=True))


_HINTS = {  # chunk -> its data for (grey8, grey16, rgb8)
    b"gAMA": (struct.pack(">I", 45455),) * 3,
    b"cHRM": (struct.pack(">8I", 31270, 32900, 64000, 33000, 30000, 60000, 15000, 6000),) * 3,
    b"sRGB": (b"\x00",) * 3,
    b"iCCP": (b"profile\x00\x00" + zlib.compress(bytes(200)),) * 3,
    b"bKGD": (struct.pack(">H", 100), struct.pack(">H", 40000), struct.pack(">3H", 1, 2, 3)),
    b"sBIT": (b"\x05", b"\x0c", b"\x05\x05\x05"),
    b"pHYs": (struct.pack(">IIB", 2835, 2835, 1),) * 3,
    b"tIME": (struct.pack(">HBBBBB", 2026, 11, 29, 7, 30, 0),) * 3,
    b"zTXt": (b"Comment\x00\x00" + zlib.compress(b"vslam"),) * 3,
    b"iTXt": (b"Comment\x00\x00\x00\x00\x00vslam",) * 3,
}


@pytest.mark.parametrize("chunk", sorted(_HINTS))
def test_chunks_opencv_does_not_apply_keep_the_fast_path(chunk):
    """Colour-space and display hints, text, time, pixel size: OpenCV decodes the same pixels with
    them, so they are decoded here too (``png._HARMLESS``)."""
    assert chunk in png._HARMLESS
    for data_of, img in zip(_HINTS[chunk], _images(np.random.default_rng(11)).values()):
        data = _png(img, extra=((chunk, data_of),))
        for grey in (False, True) if img.ndim == 2 and img.dtype == np.uint8 else (False,):
            ours = png.decode(data, grayscale=grey)
            assert ours is not None
            np.testing.assert_array_equal(ours, _opencv(data, grayscale=grey))


@pytest.mark.parametrize("level", [0, 1, 9])
def test_libpng_files_decode_as_opencv(tmp_path, level):
    """OpenCV's own PNGs (libpng's adaptive filter choice) of an image with texture and flat parts."""
    rng = np.random.default_rng(level)
    base = cv2.resize(rng.integers(0, 256, (12, 16), dtype=np.uint8), (160, 120), interpolation=cv2.INTER_CUBIC)
    for img in (base, cv2.merge([base, base[::-1], 255 - base]), base.astype(np.uint16) * 251):
        ok, enc = cv2.imencode(".png", img, [cv2.IMWRITE_PNG_COMPRESSION, level])
        assert ok
        ours = png.decode(enc, grayscale=False)
        assert ours is not None
        np.testing.assert_array_equal(ours, cv2.imdecode(enc, cv2.IMREAD_UNCHANGED))


def test_files_left_to_opencv():
    """None, so that OpenCV decodes (or refuses) them: colour conversions, other colour types and
    depths, interlacing, chunks that can change the pixels, damaged streams and files."""
    rng = np.random.default_rng(3)
    imgs = _images(rng)
    grey = _png(imgs["grey8"])
    assert png.decode(grey, grayscale=False) is not None
    assert png.decode(_png(imgs["grey16"]), grayscale=True) is None  # OpenCV scales to 8 bits
    assert png.decode(_png(imgs["rgb8"]), grayscale=True) is None  # OpenCV converts to grey
    assert png.decode(_png(imgs["grey8"], interlace=1), grayscale=False) is None
    assert png.decode(_png(imgs["grey8"], extra=((b"tRNS", b"\x00\x07"),)), grayscale=False) is None
    assert png.decode(_png(imgs["grey8"], extra=((b"eXIf", b"MM\x00*"),)), grayscale=False) is None
    assert png.decode(_png(imgs["grey8"], extra=((b"tEXt", b"Software\x00test"),)), grayscale=False) is not None
    palette = grey.replace(grey[8:33], _chunk(b"IHDR", struct.pack(">IIBBBBB", 17, 11, 8, 3, 0, 0, 0)))
    assert png.decode(palette, grayscale=False) is None
    assert png.decode(grey[: len(grey) // 2], grayscale=False) is None  # truncated
    assert png.decode(grey[:-12], grayscale=False) is None  # no IEND
    i = grey.index(b"IDAT") + 20
    assert png.decode(grey[:i] + bytes([grey[i] ^ 0x10]) + grey[i + 1:], grayscale=False) is None  # Adler-32
    bad_filter = _png(imgs["grey8"], [0] * 11)
    stream = bytearray(zlib.decompress(bad_filter[bad_filter.index(b"IDAT") + 4:][:-16]))
    stream[0] = 5  # no such filter type
    assert png.decode(_png_raw(17, 11, bytes(stream)), grayscale=False) is None
    assert png.decode(b"GIF89a" + bytes(100), grayscale=False) is None


def _png_raw(w: int, h: int, stream: bytes) -> bytes:
    """An 8-bit grey PNG holding ``stream`` (filter bytes and rows) as its image data, as given."""
    return (png.SIGNATURE + _chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 0, 0, 0, 0))
            + _chunk(b"IDAT", zlib.compress(stream)) + _chunk(b"IEND", b""))


def test_loaders_decode_as_opencv_and_still_refuse_damaged_files(tmp_path):
    img = _images(np.random.default_rng(5))
    p8, p16 = tmp_path / "a.png", tmp_path / "d.png"
    p8.write_bytes(_png(img["rgb8"]))
    np.testing.assert_array_equal(load_image(p8), cv2.imread(str(p8), cv2.IMREAD_UNCHANGED))
    np.testing.assert_array_equal(load_image(p8, grayscale=True), cv2.imread(str(p8), cv2.IMREAD_GRAYSCALE))
    p16.write_bytes(_png(img["grey16"]))
    np.testing.assert_array_equal(load_depth(p16, 1000.0), cv2.imread(str(p16), cv2.IMREAD_UNCHANGED) / np.float32(1000.0))
    data = p8.read_bytes()
    p8.write_bytes(data[: len(data) // 2])
    with pytest.raises(CorruptFrameError, match="cannot be decoded"):
        load_image(p8)


def test_kernel_rows_of_one_pixel():
    """Rows shorter than a pixel's bytes back (``x < bpp`` everywhere): ``a`` and ``c`` are 0."""
    img = np.arange(6, dtype=np.uint8).reshape(6, 1) * 40
    for f in range(5):
        stream = np.frombuffer(_filtered(img, 1, [f] * 6), np.uint8)
        out = np.empty((6, 1), np.uint8)
        assert unfilter(stream, out, 1)
        np.testing.assert_array_equal(out, img)


def test_shared_sequences_decode_as_opencv(shared_data):
    """A few frames of every real sequence (grey 8-bit EuRoC and KITTI, 16-bit depth, RGB)."""
    files = []
    for pattern in ("euroc_mh01_vi_80/mav0/cam1/data/*.png", "euroc_V1_01_easy_40frames/mav0/cam0/data/*.png",
                    "kitti_odometry/sequences/07/image_0/*.png", "7scenes_redkitchen/*/*.depth.png",
                    "tum_rgbd_freiburg1_desk_9frames/rgb/*.png", "tum_rgbd_freiburg1_desk_9frames/depth/*.png"):
        found = sorted(shared_data.glob(pattern))
        assert found, pattern
        files += found[:: max(1, len(found) // 4)]
    for f in files:
        buf = np.frombuffer(f.read_bytes(), np.uint8)
        ours = png.decode(buf, grayscale=False)
        assert ours is not None, f
        np.testing.assert_array_equal(ours, cv2.imdecode(buf, cv2.IMREAD_UNCHANGED), err_msg=str(f))
