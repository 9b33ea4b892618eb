"""Fisheye (Kannala-Brandt / equidistant) end to end: a rendered fisheye sequence with a known lens,
written as an image folder with a fisheye ``camera.yaml``, through ``vslam run --camera`` (tracking,
local BA and loop closing on, map saved) and ``vslam localize`` in that map, against the pinhole run
of the same scene and path."""
from __future__ import annotations

import json

import numpy as np
import pytest

from vslam.cli import main
from vslam.datasets.calibration import Rectifier, frame_camera, read_camera_file
from vslam.datasets.synthetic import SyntheticConfig, SyntheticSequence, add_pixel_noise, default_renderer
from vslam.datasets.synthetic.fisheye import FisheyeLens
from vslam.errors import CalibrationError
from vslam.trajectory import read_tum
from vslam.eval import evaluate_trajectories

N = 40
CFG = SyntheticConfig(n_frames=N, laps=0.15, width=320, height=240, fx=262.5, fy=262.5, cx=159.5, cy=119.5,
                      pixel_noise=1.0, seed=3, stereo=False, rgbd=False)
K_FISH = np.array([[190.0, 0.0, 159.5], [0.0, 190.0, 119.5], [0.0, 0.0, 1.0]])
D_FISH = (-0.03, 0.012, -0.004, 0.0005)


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """The same 40-frame path as a pinhole (62 x 49 deg) and a fisheye (112 x 96 deg) image folder."""
    import cv2

    root = tmp_path_factory.mktemp("fisheye")
    seq = SyntheticSequence(CFG)
    lens = FisheyeLens(K_FISH, D_FISH, (CFG.width, CFG.height))
    renderer = default_renderer()
    (root / "pinhole").mkdir()
    (root / "fisheye").mkdir()
    for i, frame in enumerate(seq):
        cv2.imwrite(str(root / "pinhole" / f"{i:04d}.png"), frame.image)
        image, _ = lens.render(renderer, seq.T_world_cam[i])
        image = add_pixel_noise(image, CFG.pixel_noise, np.random.default_rng([CFG.seed, i]))
        cv2.imwrite(str(root / "fisheye" / f"{i:04d}.png"), image)
    (root / "pinhole.yaml").write_text(f"fx: 262.5\nfy: 262.5\ncx: 159.5\ncy: 119.5\nwidth: 320\nheight: 240\n")
    (root / "fisheye.yaml").write_text(lens.camera_yaml())
    return root, seq.ground_truth(), lens


def _sim3_ate(traj, gt) -> float:
    """Sim(3)-aligned ATE over every pose of ``traj`` (the evaluation `vslam eval --align sim3` runs)."""
    r = evaluate_trajectories(traj, gt, align="sim3")
    assert r.matched_poses == len(traj)
    return float(r.ate.rmse)


def _run(root, name, yaml):
    out = root / f"run_{name}"
    assert main(["run", str(root / name), "--camera", str(root / yaml), "-o", str(out), "--no-progress"]) == 0
    return out, json.loads((out / "stats.json").read_text())


def test_fisheye_lens_covers_a_wider_field_than_the_remapped_pinhole(scene):
    """The rendered lens sees 112 x 96 deg; the remapped pinhole keeps 89 x 73 deg with the default
    ``balance: 0`` (only valid pixels), 98 x 82 deg with ``balance: 1`` (black corners)."""
    root, _, lens = scene
    assert np.degrees(2 * np.array(lens.half_fov)) == pytest.approx([111.9, 95.8], abs=0.2)
    cam, rect = frame_camera(read_camera_file(root / "fisheye.yaml"))
    fov = lambda c: np.degrees(2 * np.arctan([c.width / (2 * c.fx), c.height / (2 * c.fy)]))  # noqa: E731
    assert rect is not None and fov(cam) == pytest.approx([89.4, 73.1], abs=0.2)
    wide = root / "fisheye_wide.yaml"
    wide.write_text(lens.camera_yaml() + "balance: 1.0\n")
    cam1, _ = frame_camera(read_camera_file(wide))
    assert fov(cam1) == pytest.approx([98.2, 81.8], abs=0.2)
    bad = root / "fisheye_bad.yaml"
    bad.write_text(lens.camera_yaml() + "balance: 2\n")
    with pytest.raises(CalibrationError, match="balance"):
        read_camera_file(bad)
    # a rectified pixel's ray projects, through the fisheye model, where the remap takes it from
    import cv2

    r = Rectifier(read_camera_file(root / "fisheye.yaml"))
    uv = np.array([[20.0, 30.0], [300.0, 200.0], [160.0, 120.0]])
    rays = np.c_[(uv - [cam.cx, cam.cy]) / [cam.fx, cam.fy], np.ones(3)]
    fish_uv = cv2.fisheye.projectPoints(rays.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K_FISH,
                                        np.array(D_FISH)).__getitem__(0).reshape(-1, 2)
    m = cv2.convertMaps(*r.maps_left, cv2.CV_32FC1)
    src = np.array([[m[0][int(v), int(u)], m[1][int(v), int(u)]] for u, v in uv])
    assert np.abs(src - fish_uv).max() < 0.05


def test_fisheye_run_and_localize_match_the_pinhole_run(scene):
    """Pinhole Sim(3) ATE 0.022 m, fisheye 0.007 m (the wider view constrains the pose better):
    the fisheye run must stay within 1.5x + 5 mm of the pinhole one. Localizing frames 10-29 of the
    fisheye sequence in the fisheye map: 20/20, ATE 0.003 m, within 6 mm of the run's poses."""
    root, gt, _ = scene
    out_p, s_p = _run(root, "pinhole", "pinhole.yaml")
    out_f, s_f = _run(root, "fisheye", "fisheye.yaml")
    assert "equidistant" in s_f["camera"]
    for s in (s_p, s_f):
        assert s["tracked"] == N and s["lost"] == 0 and "error" not in s
        assert s["backend"]["local_ba_calls"] >= 3 and s["loop_closing"]["keyframes_processed"] >= 3
    assert (out_f / "map").is_dir() and s_f["map_points"] > 1000
    ate_p = _sim3_ate(read_tum(out_p / "trajectory.txt"), gt)
    ate_f = _sim3_ate(read_tum(out_f / "trajectory.txt"), gt)
    assert 0.015 < ate_p < 0.03 and 0.003 < ate_f < 0.012
    assert ate_f <= 1.5 * ate_p + 0.005

    loc = root / "loc_fisheye"
    assert main(["localize", str(out_f), str(root / "fisheye"), "--camera", str(root / "fisheye.yaml"),
                 "--start-frame", "10", "--max-frames", "20", "-o", str(loc), "--no-progress"]) == 0
    s_l = json.loads((loc / "stats.json").read_text())
    assert s_l["localized"] == 20 and s_l["lost"] == 0
    traj_l = read_tum(loc / "trajectory.txt")
    assert _sim3_ate(traj_l, gt) < 0.006
    traj_f = read_tum(out_f / "trajectory.txt")
    idx = np.searchsorted(traj_f.timestamps, traj_l.timestamps - 1e-4)
    scale = np.ptp(traj_f.positions, axis=0).max() / np.ptp(gt.positions[: N], axis=0).max()
    err = np.linalg.norm(traj_l.positions - traj_f.positions[idx], axis=1) / scale  # metres
    assert np.median(err) < 0.004 and err.max() < 0.01  # measured 0.6-5.6 mm
