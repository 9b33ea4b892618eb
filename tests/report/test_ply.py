"""Reading sparse.ply: ASCII and binary, with and without colour, and broken files."""
from __future__ import annotations

import numpy as np
import pytest

from vslam.bench.fake import write_ply
from vslam.errors import MapFormatError
from vslam.report.ply import read_ply_points


def binary_ply(xyz, rgb=None, order="<", extra=True) -> bytes:
    props = ["property float x", "property float y", "property float z"]
    fields = [("x", "f4"), ("y", "f4"), ("z", "f4")]
    if extra:
        props.append("property double quality")
        fields.append(("quality", "f8"))
    if rgb is not None:
        props += ["property uchar red", "property uchar green", "property uchar blue"]
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    fmt = "binary_little_endian" if order == "<" else "binary_big_endian"
    header = "\n".join(["ply", f"format {fmt} 1.0", f"element vertex {len(xyz)}", *props,
                        "element face 0", "property list uchar int vertex_indices", "end_header"]) + "\n"
    arr = np.zeros(len(xyz), dtype=[(n, order + t) for n, t in fields])
    arr["x"], arr["y"], arr["z"] = xyz.T
    if rgb is not None:
        arr["red"], arr["green"], arr["blue"] = rgb.T
    return header.encode() + arr.tobytes()


@pytest.fixture
def cloud():
    rng = np.random.default_rng(3)
    return rng.normal(size=(50, 3)).astype(np.float32).astype(float), rng.integers(0, 256, (50, 3)).astype(np.uint8)


def test_ascii_roundtrip(tmp_path, cloud):
    xyz, rgb = cloud
    write_ply(tmp_path / "a.ply", xyz, rgb)
    got, got_rgb = read_ply_points(tmp_path / "a.ply")
    np.testing.assert_allclose(got, xyz, atol=1e-5)
    np.testing.assert_array_equal(got_rgb, rgb)
    write_ply(tmp_path / "b.ply", xyz)
    got, got_rgb = read_ply_points(tmp_path / "b.ply")
    assert got_rgb is None and got.shape == (50, 3)


@pytest.mark.parametrize("order", ["<", ">"])
def test_binary(tmp_path, cloud, order):
    xyz, rgb = cloud
    (tmp_path / "c.ply").write_bytes(binary_ply(xyz, rgb, order))
    got, got_rgb = read_ply_points(tmp_path / "c.ply")
    np.testing.assert_array_equal(got, xyz)
    np.testing.assert_array_equal(got_rgb, rgb)
    got, _ = read_ply_points(tmp_path / "c.ply", max_points=10)
    assert len(got) == 10 and np.array_equal(got[0], xyz[0]) and np.array_equal(got[-1], xyz[-1])


def test_broken_files(tmp_path, cloud):
    xyz, rgb = cloud
    (tmp_path / "t.ply").write_bytes(binary_ply(xyz, rgb)[:-10])
    with pytest.raises(MapFormatError, match="truncated"):
        read_ply_points(tmp_path / "t.ply")
    (tmp_path / "n.ply").write_text("hello")
    with pytest.raises(MapFormatError, match="not a PLY"):
        read_ply_points(tmp_path / "n.ply")
    (tmp_path / "x.ply").write_text("ply\nformat ascii 1.0\nelement vertex 1\nproperty float a\nend_header\n1\n")
    with pytest.raises(MapFormatError, match="x, y, z"):
        read_ply_points(tmp_path / "x.ply")
