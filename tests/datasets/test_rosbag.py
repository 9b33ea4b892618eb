"""ROS 1 / ROS 2 bags written with ``rosbags`` from the shared fr1 desk sequence: the run from the
bag matches the run from the folder."""
from __future__ import annotations

import json
import shutil

import cv2
import numpy as np
import pytest

from vslam.cli import main
from vslam.datasets import detect_kind, open_dataset
from vslam.datasets.tum import TUM_PRESETS
from vslam.errors import DatasetError

rosbags = pytest.importorskip("rosbags")
from rosbags.typesys import Stores, get_typestore  # noqa: E402


def _write_bag(seq, out, ros1: bool, compressed: bool = False, depth_16u: bool = False, info: bool = True,
               extra_topic: bool = False, color_stamp=None):
    """A bag of the TUM sequence's associated rgb/depth pairs (header stamps = TUM timestamps;
    ``color_stamp(k, t)``: the k-th colour message's header stamp instead, recorded at ``t``)."""
    ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    T = ts.types
    Image, Cmp, Info = T["sensor_msgs/msg/Image"], T["sensor_msgs/msg/CompressedImage"], T["sensor_msgs/msg/CameraInfo"]
    Header, Time, Roi = T["std_msgs/msg/Header"], T["builtin_interfaces/msg/Time"], T["sensor_msgs/msg/RegionOfInterest"]
    ser = ts.serialize_ros1 if ros1 else ts.serialize_cdr

    def header(t):
        sec = int(t)
        stamp = Time(sec=sec, nanosec=int(round((t - sec) * 1e9)))
        return Header(seq=0, stamp=stamp, frame_id="cam") if ros1 else Header(stamp=stamp, frame_id="cam")

    rows = [line.split() for line in (seq / "associate.txt").read_text().splitlines() if line.strip()
            and not line.startswith("#")]
    cam = TUM_PRESETS[1]
    if ros1:
        from rosbags.rosbag1 import Writer
        writer = Writer(out)
    else:
        from rosbags.rosbag2 import Writer
        writer = Writer(out, version=8)
    with writer as w:
        ctype = Cmp if compressed else Image
        c_col = w.add_connection("/camera/rgb/image_color", ctype.__msgtype__, typestore=ts)
        c_dep = w.add_connection("/camera/depth/image", Image.__msgtype__, typestore=ts)
        c_inf = w.add_connection("/camera/rgb/camera_info", Info.__msgtype__, typestore=ts) if info else None
        if extra_topic:
            c_x = w.add_connection("/camera/ir/image", Image.__msgtype__, typestore=ts)
        for k, (t_rgb, rgb, t_d, dep) in enumerate(rows):
            t_rgb, t_d = float(t_rgb), float(t_d)
            t_head = color_stamp(k, t_rgb) if color_stamp else t_rgb
            bgr = cv2.imread(str(seq / rgb), cv2.IMREAD_COLOR)
            raw = cv2.imread(str(seq / dep), cv2.IMREAD_UNCHANGED)
            h, w_ = bgr.shape[:2]
            if compressed:
                msg = Cmp(header=header(t_head), format="bgr8; png compressed",
                          data=np.frombuffer(cv2.imencode(".png", bgr)[1].tobytes(), np.uint8))
            else:
                rgb8 = np.ascontiguousarray(bgr[:, :, ::-1])
                msg = Image(header=header(t_head), height=h, width=w_, encoding="rgb8", is_bigendian=0, step=3 * w_,
                            data=rgb8.reshape(-1))
            bag_ns = int(t_rgb * 1e9) + 5_000_000  # received a little after the stamp
            w.write(c_col, bag_ns, ser(msg, ctype.__msgtype__))
            if depth_16u:
                mm = np.round(raw.astype(np.float64) / 5.0).astype(np.uint16)  # TUM 1/5000 m -> mm
                dmsg = Image(header=header(t_d), height=h, width=w_, encoding="16UC1", is_bigendian=0, step=2 * w_,
                             data=mm.view(np.uint8).reshape(-1))
            else:
                metres = raw.astype(np.float32) / np.float32(5000.0)
                dmsg = Image(header=header(t_d), height=h, width=w_, encoding="32FC1", is_bigendian=0, step=4 * w_,
                             data=metres.view(np.uint8).reshape(-1))
            w.write(c_dep, int(t_d * 1e9) + 6_000_000, ser(dmsg, Image.__msgtype__))
            if extra_topic:
                w.write(c_x, bag_ns, ser(dmsg, Image.__msgtype__))
            if info and k == 0:
                P = np.hstack([cam.K, np.zeros((3, 1))]).reshape(-1)
                kw = dict(header=header(t_rgb), height=h, width=w_, distortion_model="plumb_bob",
                          binning_x=0, binning_y=0, roi=Roi(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False))
                arrays = dict(D=np.array(cam.dist), K=cam.K.reshape(-1), R=np.eye(3).reshape(-1), P=P)
                kw.update(arrays if ros1 else {k.lower(): v for k, v in arrays.items()})
                w.write(c_inf, bag_ns, ser(Info(**kw), Info.__msgtype__))
    return out


@pytest.fixture
def fr1(shared_data):
    return shared_data / "tum_rgbd_freiburg1_desk_9frames"


def _run(path, out, *extra):
    assert main(["run", str(path), "-o", str(out), "--no-progress", *extra]) == 0
    return json.loads((out / "stats.json").read_text())


def test_ros2_bag_rgbd_equals_folder(fr1, tmp_path):
    bag = _write_bag(fr1, tmp_path / "fr1_ros2", ros1=False)
    shutil.copy(fr1 / "groundtruth.txt", tmp_path / "groundtruth.txt")
    assert detect_kind(bag) == "rosbag"
    ds = open_dataset(bag)
    assert ds.sensors == ("mono", "rgbd") and ds.sensor == "rgbd" and len(ds) == 9
    assert ds.topics == ["/camera/rgb/image_color", "/camera/depth/image"]
    assert ds.camera == TUM_PRESETS[1] and "camera_info in the bag" in ds.calibration_source
    ref = open_dataset(fr1)
    np.testing.assert_allclose(ds.timestamps, ref.timestamps, atol=1e-6)
    f_bag, f_ref = ds[4], ref[4]
    np.testing.assert_array_equal(f_bag.image, f_ref.image)
    np.testing.assert_array_equal(f_bag.depth, f_ref.depth)
    s_bag = _run(bag, tmp_path / "out_bag")
    s_ref = _run(fr1, tmp_path / "out_ref")
    assert s_bag["tracked"] == 9 and s_bag["matched_poses"] == 9
    assert s_bag["ate_rmse"] == pytest.approx(s_ref["ate_rmse"], abs=1e-6)
    assert s_ref["ate_rmse"] == pytest.approx(0.0028, abs=0.0003)


def test_ros1_bag_compressed_16u_depth(fr1, tmp_path):
    """ROS 1, PNG CompressedImage colour and 16UC1 millimetre depth (quantised: ATE close, not equal)."""
    bag = _write_bag(fr1, tmp_path / "fr1.bag", ros1=True, compressed=True, depth_16u=True)
    shutil.copy(fr1 / "groundtruth.txt", tmp_path / "groundtruth.txt")
    ds = open_dataset(bag, sensor="rgbd")
    ref = open_dataset(fr1)
    np.testing.assert_array_equal(ds[0].image, ref[0].image)
    assert np.abs(ds[0].depth - ref[0].depth).max() <= 0.0006
    s = _run(bag, tmp_path / "out")
    assert s["tracked"] == 9 and s["ate_rmse"] == pytest.approx(0.0028, abs=0.0006)
    mono = open_dataset(bag, sensor="mono")
    assert mono[0].depth is None and len(mono) == 9


def test_bag_topics_ambiguous_and_missing_info(fr1, tmp_path, capsys):
    bag = _write_bag(fr1, tmp_path / "b", ros1=False, info=False, extra_topic=True)
    with pytest.raises(DatasetError, match=r"pass --topics COLOR\[,DEPTH\|,RIGHT\].*/camera/ir/image"):
        open_dataset(bag)
    with pytest.raises(DatasetError, match="no sensor_msgs/CameraInfo"):
        open_dataset(bag, topics="/camera/rgb/image_color,/camera/depth/image")
    ds = open_dataset(bag, topics="/camera/rgb/image_color,/camera/depth/image", camera="fr1")
    assert ds.sensor == "rgbd" and ds.camera.fx == pytest.approx(517.306408)
    rc = main(["run", str(bag), "-o", str(tmp_path / "o"), "--topics", "/nope"])
    assert rc == 2 and "no image topic '/nope'" in capsys.readouterr().err


def test_ground_truth_inside_the_bag_folder_wins(fr1, tmp_path, capsys):
    """A ROS 2 bag folder with its own groundtruth.txt and a stray (garbage) one beside it: the one
    inside is used and named; the stray one never stops the run."""
    bag = _write_bag(fr1, tmp_path / "fr1_ros2", ros1=False)
    (tmp_path / "groundtruth.txt").write_text("stray file, not a trajectory\n")
    shutil.copy(fr1 / "groundtruth.txt", bag / "groundtruth.txt")
    assert open_dataset(bag).ground_truth_file() == bag / "groundtruth.txt"
    s = _run(bag, tmp_path / "out")
    assert s["gt_file"] == str((bag / "groundtruth.txt").resolve()) and s["gt_frame"] == "camera"
    assert s["matched_poses"] == 9 and s["ate_rmse"] == pytest.approx(0.0028, abs=3e-4)
    (bag / "groundtruth.txt").unlink()  # only the stray one: skipped with a warning, the run goes on
    s = _run(bag, tmp_path / "out2")
    assert s["tracked"] == 9 and "ate_rmse" not in s and "not a number" in s["gt_problem"]
