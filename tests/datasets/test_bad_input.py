"""Every kind of broken input gives one DatasetError/CalibrationError naming the file and the fix."""
from __future__ import annotations

import logging

import cv2
import numpy as np
import pytest

from vslam.datasets import open_dataset
from vslam.datasets.base import CorruptFrameError, load_image
from vslam.errors import CalibrationError, DatasetError


def _rgb(root, i):
    return sorted((root / "rgb").iterdir())[i]


def _truncate(path, keep=0.5):
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * keep)])


def test_missing_folder(tmp_path):
    with pytest.raises(DatasetError, match="no such file or folder"):
        open_dataset(tmp_path / "nope")
    with pytest.raises(DatasetError, match="nope: no such file or folder"):
        open_dataset(tmp_path / "nope", kind="tum")


def test_unrecognised_layout_and_unknown_kind(tmp_path):
    (tmp_path / "notes.txt").write_text("hello")
    with pytest.raises(DatasetError, match="unrecognised dataset layout"):
        open_dataset(tmp_path)
    with pytest.raises(DatasetError, match="unknown dataset kind 'colmap'"):
        open_dataset(tmp_path, kind="colmap")


def test_missing_rgb_list(tmp_path, make_tum):
    root = make_tum(tmp_path / "seq")
    (root / "rgb.txt").unlink()
    with pytest.raises(DatasetError, match=r"rgb.txt: not found"):
        open_dataset(root, kind="tum")


def test_missing_listed_image(tmp_path, make_tum):
    root = make_tum(tmp_path / "seq", n=12)
    _rgb(root, 0).unlink()
    with pytest.raises(DatasetError, match=r"1 of 12 image files listed are missing"):
        open_dataset(root)
    root = make_tum(tmp_path / "seq2", n=12)
    _rgb(root, 6).unlink()  # one in the middle: skipped while iterating
    ds = open_dataset(root)
    frames = list(ds)
    assert len(frames) == 11 and ds.skipped == 1


def test_truncated_first_image_is_fatal(tmp_path, make_tum):
    root = make_tum(tmp_path / "seq")
    _truncate(_rgb(root, 0))
    ds = open_dataset(root)  # opening only lists files
    with pytest.raises(DatasetError, match=r"cannot be decoded.*first frame must be readable"):
        list(ds)


def test_single_corrupt_frame_is_skipped_and_counted(tmp_path, make_tum, caplog):
    root = make_tum(tmp_path / "seq", n=12)
    bad = _rgb(root, 5)
    bad.write_bytes(b"this is not a png")
    ds = open_dataset(root)
    with caplog.at_level(logging.WARNING, logger="vslam.datasets"):
        frames = list(ds)
    assert len(frames) == 11 and ds.skipped == 1
    assert 5 not in [f.index for f in frames]
    assert any(bad.name in r.getMessage() and "skipping frame 5" in r.getMessage() for r in caplog.records)
    with pytest.raises(CorruptFrameError, match=bad.name):
        ds[5]  # direct access raises (a subclass of DatasetError)


def test_many_corrupt_frames_raise(tmp_path, make_tum):
    root = make_tum(tmp_path / "seq", n=12)
    for i in (3, 6, 9):  # raises as soon as the failures pass 10% of the range: 2 of 12
        _truncate(_rgb(root, i), 0.3)
    ds = open_dataset(root)
    with pytest.raises(DatasetError, match=r"1000.200000.png.*2 of 12 frames failed to decode, more than 10%"):
        list(ds)


def test_truncated_jpeg_is_detected(tmp_path):
    img = np.random.default_rng(1).integers(0, 255, (48, 64, 3), dtype=np.uint8)
    p = tmp_path / "a.jpg"
    cv2.imwrite(str(p), img)
    assert load_image(p).shape == (48, 64, 3)
    _truncate(p, 0.7)
    with pytest.raises(CorruptFrameError, match="truncated"):
        load_image(p)
    (tmp_path / "empty.png").write_bytes(b"")
    with pytest.raises(CorruptFrameError, match="empty"):
        load_image(tmp_path / "empty.png")


def test_missing_calibration(tmp_path, make_tum):
    root = make_tum(tmp_path / "my_sequence", camera_yaml=None)
    with pytest.raises(CalibrationError, match=r"my_sequence: no calibration.*add camera.yaml"):
        open_dataset(root)
    # a freiburg name selects the preset instead
    root = make_tum(tmp_path / "rgbd_dataset_freiburg3_x", camera_yaml=None, size=(640, 480), n=2)
    assert open_dataset(root).camera.fx == 535.4


@pytest.mark.parametrize(
    "text, match",
    [
        ("fx: 50\nfy: 51\ncx: 31.5\nwidth: 64\nheight: 48\n", "lacks 'cy'"),
        ("fx: abc\nfy: 51\ncx: 31.5\ncy: 20\nwidth: 64\nheight: 48\n", "'fx' = 'abc' is not a number"),
        ("fx: [50\nfy: 51\n", "not valid YAML"),
        ("- 1\n- 2\n", "must be a mapping"),
        ("fx: 50\nfy: 51\ncx: 31.5\ncy: 20\nwidth: 64\nheight: 48\ndist: [1, 2]\n", "'dist' needs 4 or 5"),
        ("fx: -5\nfy: 51\ncx: 31.5\ncy: 20\nwidth: 64\nheight: 48\n", "focal lengths must be positive"),
        ("fx: 50\nfy: 51\ncx: 31.5\ncy: 20\nwidth: 64\nheight: 48\ndepth_scale: 0\n", "depth_scale must be positive"),
    ],
)
def test_malformed_camera_yaml(tmp_path, make_tum, text, match):
    root = make_tum(tmp_path / "seq", camera_yaml=text, n=2)
    with pytest.raises(CalibrationError, match=match) as info:
        open_dataset(root)
    assert "camera.yaml" in str(info.value)


def test_calibration_size_mismatch(tmp_path, make_tum):
    root = make_tum(tmp_path / "seq", camera_yaml="fx: 50\nfy: 50\ncx: 32\ncy: 24\nwidth: 640\nheight: 480\n")
    with pytest.raises(DatasetError, match="image is 64x48 but the calibration says 640x480"):
        next(iter(open_dataset(root)))


def test_unsorted_and_duplicate_timestamps(tmp_path, make_tum):
    root = make_tum(tmp_path / "seq", n=5)
    lines = (root / "rgb.txt").read_text().splitlines()
    (root / "rgb.txt").write_text("\n".join([lines[0], lines[1], lines[3], lines[2], *lines[4:]]) + "\n")
    with pytest.raises(DatasetError, match=r"rgb.txt: timestamps are not sorted \(entry 3"):
        open_dataset(root)
    (root / "rgb.txt").write_text("\n".join([lines[0], lines[1], lines[1], *lines[2:]]) + "\n")
    with pytest.raises(DatasetError, match=r"rgb.txt: duplicate timestamp"):
        open_dataset(root)
    (root / "rgb.txt").write_text("\n".join([lines[0], "abc rgb/x.png"]) + "\n")
    with pytest.raises(DatasetError, match=r"rgb.txt:2: timestamp 'abc' is not a number"):
        open_dataset(root)


def test_depth_of_wrong_size(tmp_path, make_tum):
    root = make_tum(tmp_path / "seq", n=3)
    dpath = sorted((root / "depth").iterdir())[1]
    cv2.imwrite(str(dpath), np.ones((24, 32), np.uint16))
    ds = open_dataset(root)
    frames = list(ds)  # a frame of the wrong size is skipped and counted, not fatal
    assert [f.index for f in frames] == [0, 2] and ds.skipped == 1
    with pytest.raises(DatasetError, match=r"depth image is 32x24 but the colour image is 64x48"):
        ds[1]


def test_depth_not_16bit(tmp_path, make_tum):
    root = make_tum(tmp_path / "seq", n=2)
    dpath = sorted((root / "depth").iterdir())[0]
    cv2.imwrite(str(dpath), np.zeros((48, 64, 3), np.uint8))
    with pytest.raises(DatasetError, match="single-channel 16-bit"):
        open_dataset(root)[0]


def test_depth_lists_that_do_not_match(tmp_path, make_tum):
    root = make_tum(tmp_path / "seq", n=3)
    text = (root / "depth.txt").read_text().replace("1000.", "2000.")
    (root / "depth.txt").write_text(text)
    with pytest.raises(DatasetError, match="no depth timestamp is within 0.02 s"):
        open_dataset(root)
