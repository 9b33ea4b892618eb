"""load_depth's one-pass compiled conversion against NumPy's ``raw.astype(float32) / scale`` with
the invalid values zeroed: identical float32 bits, for every 16-bit value."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from vslam.datasets.depth_kernels import scale_depth
from vslam.datasets.images import load_depth


def _ref(raw, scale, invalid):
    depth = raw.astype(np.float32) / np.float32(scale)
    for v in invalid:
        if v != 0:
            depth[raw == v] = 0.0
    return depth


@pytest.mark.parametrize("scale", [1000.0, 5000.0, 5208.0, 1.0, 0.001])
def test_every_uint16_value_converts_like_numpy(scale):
    raw = np.arange(65536, dtype=np.uint16).reshape(256, 256)
    got = np.empty(raw.shape, np.float32)
    scale_depth(raw, np.float32(scale), 65535, got)
    assert got.tobytes() == _ref(raw, scale, (0, 65535)).tobytes()
    assert got[0, 0] == 0.0 and got[-1, -1] == 0.0 and got[0, 1] == np.float32(1) / np.float32(scale)
    scale_depth(raw, np.float32(scale), -1, got)
    assert got.tobytes() == _ref(raw, scale, (0,)).tobytes()


@pytest.mark.parametrize("invalid", [(0,), (0, 65535), (65535,), (0, 7, 65535), ()])
def test_load_depth_png_identical(tmp_path, invalid):
    rng = np.random.default_rng(len(invalid))
    raw = rng.integers(0, 65536, (48, 64), dtype=np.uint16)
    raw[::5, ::3] = 65535
    raw[1::7, ::2] = 0
    raw[2, :] = 7
    path = tmp_path / "d.png"
    cv2.imwrite(str(path), raw)
    got = load_depth(path, 1000.0, (48, 64), invalid=invalid)
    assert got.dtype == np.float32 and got.tobytes() == _ref(raw, 1000.0, invalid).tobytes()
    assert (got[2] == 0).all() == (7 in invalid)
