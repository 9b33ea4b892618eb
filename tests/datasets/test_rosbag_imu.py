"""``sensor_msgs/Imu`` from ROS 1/2 bags written here with ``rosbags`` from REAL EuRoC MH_01 (80 cam0
frames, the 200 Hz ``imu0/data.csv``): the bag's IMU is the CSV's, sample for sample, and a
``mono-inertial`` run of the bag initializes the IMU as the EuRoC folder's run does."""
from __future__ import annotations

import json
import shutil

import cv2
import numpy as np
import pytest
import yaml

from vslam.cli import main
from vslam.datasets import open_dataset
from vslam.datasets.imu import dataset_imu, load_imu_csv
from vslam.errors import DatasetError

rosbags = pytest.importorskip("rosbags")
from rosbags.typesys import Stores, get_typestore  # noqa: E402

MH01 = "euroc_mh01_vi_80"


def _write_mh01_bag(src, out, ros1: bool, imu_topics=("/imu0",), frames: int = 80):
    """cam0 as ``mono8`` Images with its raw (distorted) camera_info, and every imu0 sample as an Imu
    message on each of ``imu_topics``; the camera-IMU calibration beside the bag (Kalibr camchain
    from cam0's ``T_BS``, EuRoC's imu0 ``sensor.yaml``)."""
    ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    T = ts.types
    Image, Info, Imu = T["sensor_msgs/msg/Image"], T["sensor_msgs/msg/CameraInfo"], T["sensor_msgs/msg/Imu"]
    Header, Time, Roi = T["std_msgs/msg/Header"], T["builtin_interfaces/msg/Time"], T["sensor_msgs/msg/RegionOfInterest"]
    Vec, Quat = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Quaternion"]
    ser = ts.serialize_ros1 if ros1 else ts.serialize_cdr

    def header(ns: int):
        stamp = Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)
        return Header(seq=0, stamp=stamp, frame_id="x") if ros1 else Header(stamp=stamp, frame_id="x")

    ds = open_dataset(src, sensor="mono")
    cam = ds.cam0
    mav0 = src / "mav0"
    images = [line.split(",") for line in (mav0 / "cam0" / "data.csv").read_text().splitlines()
              if line.strip() and not line.startswith("#")][:frames]
    imu_rows = [line.split(",") for line in (mav0 / "imu0" / "data.csv").read_text().splitlines()
                if line.strip() and not line.startswith("#")]
    if ros1:
        from rosbags.rosbag1 import Writer
        writer = Writer(out)
    else:
        from rosbags.rosbag2 import Writer
        writer = Writer(out, version=8)
    zero9 = np.zeros(9)
    with writer as w:
        c_img = w.add_connection("/cam0/image_raw", Image.__msgtype__, typestore=ts)
        c_inf = w.add_connection("/cam0/camera_info", Info.__msgtype__, typestore=ts)
        c_imu = [w.add_connection(t, Imu.__msgtype__, typestore=ts) for t in imu_topics]
        msgs = []
        for row in imu_rows:
            ns = int(row[0])
            v = [float(x) for x in row[1:7]]
            m = Imu(header=header(ns), orientation=Quat(x=0.0, y=0.0, z=0.0, w=1.0), orientation_covariance=zero9,
                    angular_velocity=Vec(x=v[0], y=v[1], z=v[2]), angular_velocity_covariance=zero9,
                    linear_acceleration=Vec(x=v[3], y=v[4], z=v[5]), linear_acceleration_covariance=zero9)
            msgs += [(ns + 1_000_000, c, ser(m, Imu.__msgtype__)) for c in c_imu]
        for k, (ns, name) in enumerate(images):
            ns = int(ns)
            gray = cv2.imread(str(mav0 / "cam0" / "data" / name.strip()), cv2.IMREAD_GRAYSCALE)
            h, w_ = gray.shape
            msgs.append((ns + 5_000_000, c_img, ser(Image(header=header(ns), height=h, width=w_, encoding="mono8",
                                                          is_bigendian=0, step=w_, data=gray.reshape(-1)),
                                                    Image.__msgtype__)))
            if k == 0:
                P = np.hstack([cam.K, np.zeros((3, 1))]).reshape(-1)
                kw = dict(header=header(ns), height=h, width=w_, distortion_model="plumb_bob", binning_x=0,
                          binning_y=0, roi=Roi(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False))
                arrays = dict(D=np.array(cam.dist_coeffs, float).reshape(-1), K=cam.K.reshape(-1),
                              R=np.eye(3).reshape(-1), P=P)
                kw.update(arrays if ros1 else {k.lower(): v for k, v in arrays.items()})
                msgs.append((ns + 5_000_000, c_inf, ser(Info(**kw), Info.__msgtype__)))
        for t_ns, conn, data in sorted(msgs, key=lambda m: m[0]):
            w.write(conn, t_ns, data)
    calib_dir = out if out.is_dir() else out.parent
    T_cam_imu = np.linalg.inv(ds.T_body_cam0)  # EuRoC: the IMU is the body frame
    (calib_dir / "camchain-imucam.yaml").write_text(yaml.safe_dump(
        {"cam0": {"T_cam_imu": T_cam_imu.tolist(), "timeshift_cam_imu": 0.0}}))
    shutil.copy(mav0 / "imu0" / "sensor.yaml", calib_dir / "sensor.yaml")
    return out


@pytest.mark.shared
@pytest.mark.parametrize("ros1", [True, False])
def test_bag_imu_is_the_csv(shared_data, tmp_path, ros1):
    bag = _write_mh01_bag(shared_data / MH01, tmp_path / ("mh01.bag" if ros1 else "mh01"), ros1, frames=3)
    ds = open_dataset(bag, sensor="mono")
    csv = load_imu_csv(shared_data / MH01 / "mav0" / "imu0" / "data.csv")
    imu, calib = dataset_imu(ds)
    assert len(imu) == len(csv) == 1192
    assert np.abs(imu.timestamps - csv.timestamps).max() < 1e-9 * max(1.0, csv.timestamps.max() * 1e-6)
    assert np.array_equal(imu.gyro, csv.gyro) and np.array_equal(imu.accel, csv.accel)
    euroc = dataset_imu(open_dataset(shared_data / MH01, sensor="mono"))[1]
    assert np.allclose(calib.T_imu_cam, euroc.T_imu_cam, atol=1e-12)
    assert calib.gyro_noise_density == euroc.gyro_noise_density
    assert calib.accel_random_walk == euroc.accel_random_walk


@pytest.mark.shared
def test_bag_imu_topic_choice(shared_data, tmp_path):
    """Two Imu topics: one error naming them; ``--topics`` picks one beside the image topic."""
    bag = _write_mh01_bag(shared_data / MH01, tmp_path / "two", False, imu_topics=("/imu0", "/imu1"), frames=2)
    with pytest.raises(DatasetError, match=r"cannot choose the IMU topic automatically \(/imu0, /imu1\)"):
        dataset_imu(open_dataset(bag, sensor="mono"))
    ds = open_dataset(bag, sensor="mono", topics="/imu1")
    assert ds.topics == ["/cam0/image_raw"] and dataset_imu(ds)[0].source.endswith("topic /imu1")
    ds = open_dataset(bag, sensor="mono", topics="/cam0/image_raw,/imu0")
    assert dataset_imu(ds)[0].source.endswith("topic /imu0")


@pytest.mark.shared
def test_mono_inertial_run_from_a_bag(shared_data, tmp_path):
    """``vslam run BAG --sensor mono-inertial`` (ROS 2, cam0's ground truth as ``groundtruth.txt`` in
    the bag folder): the IMU from the bag initializes and predicts as from the EuRoC folder. Measured:
    initialized at frame 40 after 2.00 s, scale 0.5847, ATE 0.0030 m, the EuRoC folder's run to 1e-8 m
    (poses equal to ~1e-8: the stamps pass through float seconds differently)."""
    from vslam.trajectory import write_tum

    bag = _write_mh01_bag(shared_data / MH01, tmp_path / "mh01", False)
    write_tum(bag / "groundtruth.txt", open_dataset(shared_data / MH01, sensor="mono").ground_truth())
    out = tmp_path / "run"
    assert main(["run", str(bag), "--sensor", "mono-inertial", "-o", str(out), "--no-progress"]) == 0
    s = json.loads((out / "stats.json").read_text())
    assert s["sensor"] == "mono-inertial" and s["frames"] == 80 and s["tracked"] == 80
    assert s["imu_initialized"] and s["imu_init_frame"] <= 45 and s["imu_init_time_s"] <= 2.5   # measured 40, 2.00
    assert s["ate_rmse"] <= 0.005                                  # measured 0.0030 (SE(3), metric)
    assert (out / "imu_states.csv").is_file()
