"""A written synthetic sequence reads back through the real TUM reader with the exact ground truth."""
from __future__ import annotations

import numpy as np
import pytest
import yaml

from vslam.datasets.synthetic import DEPTH_SCALE, SyntheticConfig, SyntheticSequence, depth_to_png, render_sequence
from vslam.trajectory import read_tum

CFG = SyntheticConfig(n_frames=4, pixel_noise=2.0, depth_noise=0.003, missing_depth=0.05, seed=3, start_time=100.0)


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    return render_sequence(tmp_path_factory.mktemp("synth") / "seq", CFG)


def test_layout_and_camera_yaml(written):
    for name in ("rgb.txt", "depth.txt", "right.txt", "groundtruth.txt", "camera.yaml"):
        assert (written / name).is_file(), name
    assert len(list((written / "rgb").glob("*.png"))) == CFG.n_frames
    cam = yaml.safe_load((written / "camera.yaml").read_text())
    assert cam == {
        "fx": 525.0, "fy": 525.0, "cx": 319.5, "cy": 239.5, "width": 640, "height": 480,
        "dist": [0.0] * 5, "baseline": 0.1, "depth_scale": 5000.0, "fps": 30.0,
    }
    rgb_lines = [l.split() for l in (written / "rgb.txt").read_text().splitlines() if not l.startswith("#")]
    right_lines = [l.split() for l in (written / "right.txt").read_text().splitlines() if not l.startswith("#")]
    assert [r[0] for r in rgb_lines] == [r[0] for r in right_lines] == ["100.000000", "100.033333", "100.066667", "100.100000"]
    assert rgb_lines[1][1] == "rgb/100.033333.png" and right_lines[1][1] == "right/100.033333.png"
    gt = read_tum(written / "groundtruth.txt")
    assert np.abs(gt.T_world_cam - SyntheticSequence(CFG).T_world_cam).max() < 1e-6


def test_reads_back_through_tum_reader(written):
    datasets = pytest.importorskip("vslam.datasets")
    if not hasattr(datasets, "open_dataset"):
        pytest.skip("dataset readers not available yet")
    mem = SyntheticSequence(CFG)
    ds = datasets.open_dataset(written)
    assert len(ds) == CFG.n_frames and ds.sensor == "rgbd"
    for f, g in zip(ds, mem):
        assert f.timestamp == pytest.approx(g.timestamp, abs=1e-6)
        assert np.abs(f.T_world_cam - g.T_world_cam).max() < 1e-6
        assert np.array_equal(f.image, g.image)
        assert np.abs(f.depth - g.depth).max() <= 0.5 / DEPTH_SCALE + 1e-6
        assert np.array_equal(f.depth == 0, g.depth == 0)
        assert f.camera.fx == 525.0 and f.camera.cx == 319.5 and f.camera.baseline == 0.1
    stereo = datasets.open_dataset(written, sensor="stereo")
    f0, g0 = next(iter(stereo)), mem[0]
    assert np.array_equal(f0.image_right, g0.image_right)
    assert stereo.camera.baseline == pytest.approx(0.1)
    gt = ds.ground_truth()
    assert np.abs(gt.T_world_cam - mem.T_world_cam).max() < 1e-6


def test_depth_png_quantization():
    d = np.array([[0.0, 1.23456, 13.2, -1.0]], np.float32)
    raw = depth_to_png(d)
    assert raw.dtype == np.uint16
    assert raw.tolist() == [[0, 6173, 0, 0]]  # out of the 16-bit range -> invalid (0)


def test_mono_only_sequence(tmp_path):
    out = render_sequence(tmp_path / "mono", SyntheticConfig(n_frames=2, stereo=False, rgbd=False))
    assert (out / "rgb.txt").is_file() and not (out / "depth.txt").exists() and not (out / "right.txt").exists()
