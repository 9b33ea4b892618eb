"""PLY writer/reader: exact round trips (binary and ASCII), Open3D cross-checks, broken files."""
from __future__ import annotations

import numpy as np
import pytest

from vslam.errors import MapFormatError, VslamError
from vslam.reconstruction.ply import read_ply, write_mesh, write_ply, write_point_cloud
from vslam.reconstruction.sparse import export_sparse


@pytest.fixture
def cloud():
    rng = np.random.default_rng(1)
    pts = rng.normal(scale=3.0, size=(200, 3)).astype(np.float32)
    rgb = rng.integers(0, 256, (200, 3)).astype(np.uint8)
    nrm = rng.normal(size=(200, 3)).astype(np.float32)
    return pts, rgb, nrm / np.linalg.norm(nrm, axis=1, keepdims=True)


@pytest.fixture
def mesh():
    """A unit cube: 8 vertices, 12 outward triangles."""
    v = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], np.float32)
    f = np.array([[0, 2, 1], [1, 2, 3], [4, 5, 6], [5, 7, 6], [0, 1, 4], [1, 5, 4],
                  [2, 6, 3], [3, 6, 7], [0, 4, 2], [2, 4, 6], [1, 3, 5], [3, 7, 5]], np.int32)
    rgb = (v * 255).astype(np.uint8)
    return v, f, rgb


@pytest.mark.parametrize("binary", [True, False])
def test_point_cloud_round_trip_is_exact(tmp_path, cloud, binary):
    pts, rgb, nrm = cloud
    path = write_point_cloud(tmp_path / "c.ply", pts, rgb, nrm, binary=binary)
    got = read_ply(path)
    assert got.faces is None and not got.is_mesh
    assert got.points.dtype == np.float32
    np.testing.assert_array_equal(got.points, pts)
    np.testing.assert_array_equal(got.colors, rgb)
    np.testing.assert_array_equal(got.normals, nrm.astype(np.float32))


@pytest.mark.parametrize("binary", [True, False])
def test_float64_points_round_trip_exactly(tmp_path, binary):
    pts = np.random.default_rng(2).normal(size=(50, 3)) * np.pi
    got = read_ply(write_ply(tmp_path / "d.ply", pts, binary=binary))
    assert got.points.dtype == np.float64 and got.colors is None and got.normals is None
    np.testing.assert_array_equal(got.points, pts)


@pytest.mark.parametrize("binary", [True, False])
def test_mesh_round_trip_is_exact(tmp_path, mesh, binary):
    v, f, rgb = mesh
    got = read_ply(write_mesh(tmp_path / "m.ply", v, f, rgb, binary=binary))
    assert got.is_mesh
    np.testing.assert_array_equal(got.points, v)
    np.testing.assert_array_equal(got.faces, f)
    np.testing.assert_array_equal(got.colors, rgb)


def test_binary_is_compact_and_header_is_standard(tmp_path, cloud):
    pts, rgb, _ = cloud
    path = write_point_cloud(tmp_path / "c.ply", pts, rgb)
    data = path.read_bytes()
    header, body = data.split(b"end_header\n", 1)
    assert header.startswith(b"ply\nformat binary_little_endian 1.0\n")
    assert b"property float x" in header and b"property uchar red" in header
    assert len(body) == len(pts) * (3 * 4 + 3)


def test_open3d_reads_our_files(tmp_path, cloud, mesh):
    o3d = pytest.importorskip("open3d")
    pts, rgb, nrm = cloud
    for binary in (True, False):
        p = write_point_cloud(tmp_path / f"c{binary}.ply", pts, rgb, nrm, binary=binary)
        pcd = o3d.io.read_point_cloud(str(p))
        np.testing.assert_allclose(np.asarray(pcd.points), pts, rtol=0, atol=1e-6)
        np.testing.assert_allclose(np.asarray(pcd.colors) * 255.0, rgb, atol=1e-3)
        np.testing.assert_allclose(np.asarray(pcd.normals), nrm, atol=1e-6)
        v, f, vrgb = mesh
        m = o3d.io.read_triangle_mesh(str(write_mesh(tmp_path / f"m{binary}.ply", v, f, vrgb, binary=binary)))
        np.testing.assert_array_equal(np.asarray(m.triangles), f)
        np.testing.assert_allclose(np.asarray(m.vertices), v)
        assert m.is_watertight()


def test_we_read_open3d_files(tmp_path, mesh):
    o3d = pytest.importorskip("open3d")
    v, f, rgb = mesh
    m = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(v.astype(float)), o3d.utility.Vector3iVector(f))
    m.vertex_colors = o3d.utility.Vector3dVector(rgb / 255.0)
    for ascii_ in (False, True):
        p = tmp_path / f"o3d{ascii_}.ply"
        assert o3d.io.write_triangle_mesh(str(p), m, write_ascii=ascii_)
        got = read_ply(p)
        np.testing.assert_allclose(got.points, v)
        np.testing.assert_array_equal(got.faces, f)
        np.testing.assert_array_equal(got.colors, rgb)


def test_quads_big_endian_and_extra_properties(tmp_path):
    header = ("ply\nformat binary_big_endian 1.0\ncomment hand made\nelement vertex 4\nproperty double x\n"
              "property double y\nproperty double z\nproperty float quality\nelement face 1\n"
              "property list uchar uint vertex_indices\nelement extra 2\nproperty short s\nend_header\n")
    v = np.zeros(4, dtype=[("x", ">f8"), ("y", ">f8"), ("z", ">f8"), ("q", ">f4")])
    v["x"] = [0, 1, 1, 0]
    v["y"] = [0, 0, 1, 1]
    face = np.array([4], ">u1").tobytes() + np.array([0, 1, 2, 3], ">u4").tobytes()
    (tmp_path / "q.ply").write_bytes(header.encode() + v.tobytes() + face + np.array([7, 8], ">i2").tobytes())
    got = read_ply(tmp_path / "q.ply")
    np.testing.assert_array_equal(got.points[:, 0], [0, 1, 1, 0])
    np.testing.assert_array_equal(got.faces, [[0, 1, 2], [0, 2, 3]])  # fan triangulation of the quad


def test_broken_files_raise(tmp_path, cloud):
    pts, rgb, _ = cloud
    good = write_point_cloud(tmp_path / "c.ply", pts, rgb).read_bytes()
    (tmp_path / "trunc.ply").write_bytes(good[:-10])
    with pytest.raises(MapFormatError, match="truncated"):
        read_ply(tmp_path / "trunc.ply")
    (tmp_path / "nohdr.ply").write_bytes(good.split(b"end_header")[0])
    with pytest.raises(MapFormatError, match="end_header"):
        read_ply(tmp_path / "nohdr.ply")
    (tmp_path / "notply.ply").write_bytes(b"OFF\n3 1 0\n")
    with pytest.raises(MapFormatError, match="not a PLY"):
        read_ply(tmp_path / "notply.ply")
    (tmp_path / "badascii.ply").write_text("ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\n"
                                           "property float y\nproperty float z\nend_header\n1 2 3\n4 5\n")
    with pytest.raises(MapFormatError):
        read_ply(tmp_path / "badascii.ply")
    with pytest.raises(VslamError, match="no such"):
        read_ply(tmp_path / "missing.ply")
    with pytest.raises(VslamError, match="outside"):
        write_ply(tmp_path / "bad.ply", pts, faces=np.array([[0, 1, 500]]))


def test_export_sparse_drops_non_finite(tmp_path):
    X = np.array([[0.0, 1.0, 2.0], [np.nan, 0.0, 0.0], [3.0, 4.0, 5.0]])
    rgb = np.array([[1, 2, 3], [4, 5, 6], [7, 8, 9]], np.uint8)
    got = read_ply(export_sparse(tmp_path / "sparse.ply", X, rgb))
    np.testing.assert_array_equal(got.points, X[[0, 2]])
    np.testing.assert_array_equal(got.colors, rgb[[0, 2]])
    assert len(read_ply(export_sparse(tmp_path / "empty.ply", np.zeros((0, 3)))).points) == 0
