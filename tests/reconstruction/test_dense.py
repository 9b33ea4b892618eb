"""TSDF fusion: accuracy against the synthetic scene's true surfaces, real TUM RGB-D and KITTI stereo."""
from __future__ import annotations

import numpy as np
import pytest

from vslam.errors import VslamError
from vslam.reconstruction.ply import read_ply

pytest.importorskip("open3d")

from vslam.reconstruction.dense import TSDFConfig, TSDFFusion, frame_depth, fuse_tsdf  # noqa: E402


def test_rgbd_fusion_lies_on_the_true_surfaces(synthetic_frames, scene_distance, tmp_path):
    poses = [f.T_world_cam for f in synthetic_frames]
    res = fuse_tsdf(synthetic_frames, poses, voxel_size=0.02, sdf_trunc=0.06, depth_max=4.0)
    assert res.n_frames == len(synthetic_frames)
    d = scene_distance(res.vertices)
    # exact depth: the error is marching-cubes interpolation only (measured mean 1.6 mm, p99 1.2 cm)
    assert len(res.vertices) > 20000 and len(res.faces) > 30000
    assert d.mean() < 0.005, d.mean()
    assert np.percentile(d, 99) < 0.03
    dp = scene_distance(res.points)
    assert len(res.points) > 20000 and dp.mean() < 0.005
    # the whole 6 x 4 x 3 m room is seen
    np.testing.assert_allclose(np.ptp(res.vertices, axis=0), [6.0, 4.0, 3.0], atol=0.05)
    # colours come from the images (the textured walls are not one grey)
    assert res.vertex_colors.dtype == np.uint8 and res.vertex_colors.std(axis=0).min() > 20
    paths = res.save(tmp_path)
    mesh = read_ply(paths["mesh"])
    assert len(mesh.faces) == len(res.faces)
    np.testing.assert_allclose(mesh.points, res.vertices, atol=1e-5)
    assert len(read_ply(paths["dense"]).points) == len(res.points)


def test_noisy_rgbd_fusion_averages_the_noise(scene_distance, small_config):
    import dataclasses

    from vslam.datasets.synthetic import SyntheticSequence

    cfg = dataclasses.replace(small_config, depth_noise=0.01, missing_depth=0.2, stereo=False, seed=3)
    seq = SyntheticSequence(cfg)
    frames = [seq[i] for i in range(6)]  # consecutive views: the same walls seen 6 times
    single = fuse_tsdf(frames[:1], voxel_size=0.03, sdf_trunc=0.09, point_cloud=False)
    many = fuse_tsdf(frames, voxel_size=0.03, sdf_trunc=0.09, point_cloud=False)
    e1, e6 = scene_distance(single.vertices).mean(), scene_distance(many.vertices).mean()
    assert e6 < 0.01, e6  # 1 cm depth noise, 20 % missing depth
    assert e6 < 0.8 * e1, (e1, e6)  # fusing more views averages the noise down


def test_stereo_fusion_lies_near_the_true_surfaces(synthetic_frames, scene_distance):
    frames = [f for f in synthetic_frames]
    res = fuse_tsdf(frames, voxel_size=0.03, sdf_trunc=0.09, depth_source="stereo", depth_max=3.0)
    d = scene_distance(res.vertices)
    # SGBM on a 320 px rig with fx B = 26 px m: sigma_z ~ 3 cm at 3 m (measured mean ~1.4 cm)
    assert len(res.vertices) > 10000
    assert d.mean() < 0.03, d.mean()
    assert np.median(d) < 0.02


def test_poses_are_t_world_cam(synthetic_frames, scene_distance):
    """Feeding the inverse poses (a common mix-up) must not pass: the check is sensitive to it."""
    frames = synthetic_frames[:2]
    wrong = [np.linalg.inv(f.T_world_cam) for f in frames]
    res = fuse_tsdf(frames, wrong, voxel_size=0.04, sdf_trunc=0.16, point_cloud=False)
    assert scene_distance(res.vertices).mean() > 0.05


def test_frame_depth_sources_and_errors(synthetic_frames):
    f = synthetic_frames[0]
    rgb, depth, cam = frame_depth(f, TSDFConfig(depth_max=3.0))
    assert rgb.shape == (240, 320, 3) and rgb.dtype == np.uint8
    np.testing.assert_array_equal(rgb[..., 0], f.image[..., 2])  # BGR -> RGB
    assert depth.max() <= 3.0 and np.array_equal(depth > 0, (f.depth > 0) & (f.depth <= 3.0))
    _, sdepth, _ = frame_depth(f, TSDFConfig(depth_source="stereo"))
    assert (sdepth > 0).mean() > 0.3
    from vslam.datasets.frame import Frame

    bare = Frame(0, 0.0, f.image, f.camera)
    with pytest.raises(VslamError, match="neither depth nor a right image"):
        frame_depth(bare)
    with pytest.raises(VslamError, match="no pose"):
        TSDFFusion(TSDFConfig()).integrate_frame(bare)
    with pytest.raises(VslamError, match="no frame was fused"):
        fuse_tsdf([f], [None])
    with pytest.raises(VslamError, match="depth_source"):
        TSDFConfig(depth_source="lidar")


def test_missing_open3d_gives_install_hint(monkeypatch):
    import builtins

    real_import = builtins.__import__

    def fake_import(name, *args, **kwargs):
        if name == "open3d":
            raise ImportError("No module named 'open3d'")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", fake_import)
    with pytest.raises(VslamError, match=r"pip install 'vslam\[dense\]'"):
        TSDFFusion(TSDFConfig())


def test_tum_fr1_desk_fuses_to_a_plausible_mesh(shared_data):
    from vslam.datasets import open_dataset

    ds = open_dataset(shared_data / "tum_rgbd_freiburg1_desk_9frames", kind="tum", sensor="rgbd")
    frames = list(ds)
    assert len(frames) == 9 and all(f.T_world_cam is not None for f in frames)
    res = fuse_tsdf(frames, voxel_size=0.025, sdf_trunc=0.1, depth_max=3.0)
    assert len(res.vertices) > 5000 and len(res.faces) > 8000
    extent = np.ptp(res.vertices, axis=0)
    assert np.all(extent > 0.3) and np.all(extent < 5.0), extent
    # the fused surface agrees with a frame's own measured depth where both exist
    f = frames[4]
    rgb, depth, cam = frame_depth(f, TSDFConfig(depth_max=3.0))
    T_cam_world = np.linalg.inv(f.T_world_cam)
    X = res.vertices @ T_cam_world[:3, :3].T + T_cam_world[:3, 3]
    X = X[X[:, 2] > 0.1]
    uv = np.round(cam.project(X)).astype(int)
    inside = cam.in_image(uv)
    z_meas = depth[uv[inside, 1], uv[inside, 0]]
    z_mesh = X[inside, 2]
    ok = z_meas > 0
    front = np.abs(z_mesh[ok] - z_meas[ok]) < 0.1  # ignore vertices hidden behind nearer surfaces
    assert front.mean() > 0.7
    assert np.median(np.abs(z_mesh[ok][front] - z_meas[ok][front])) < 0.015


def test_kitti_stereo_fusion_is_non_empty(shared_data):
    from vslam.datasets import open_dataset

    ds = open_dataset(shared_data / "kitti_odometry" / "sequences" / "06", kind="kitti", sensor="stereo")
    frames = [ds[i] for i in range(5)]
    res = fuse_tsdf(frames, voxel_size=0.3, sdf_trunc=1.2, depth_max=25.0)
    assert len(res.points) > 5000 and len(res.vertices) > 5000
    extent = np.ptp(res.points, axis=0)
    assert 10.0 < extent.max() < 80.0, extent
    # the road: KITTI's cameras are 1.65 m above it (y points down); points 5-12 m straight ahead
    # and low in the first camera's frame must lie on it
    T_cam0_world = np.linalg.inv(frames[0].T_world_cam)
    X = res.points @ T_cam0_world[:3, :3].T + T_cam0_world[:3, 3]
    road = X[(X[:, 2] > 5) & (X[:, 2] < 12) & (np.abs(X[:, 0]) < 3) & (X[:, 1] > 0.5)]
    assert len(road) > 100
    assert abs(np.median(road[:, 1]) - 1.65) < 0.2, np.median(road[:, 1])
