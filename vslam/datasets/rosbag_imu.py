"""``sensor_msgs/Imu`` of a ROS 1/2 bag as :class:`vslam.inertial.ImuMeasurements` (the IMU of
:class:`vslam.datasets.rosbag.RosbagDataset`).

Topic: the bag's one ``sensor_msgs/Imu`` topic, or the one named in ``--topics`` (beside the image
topics, in any position: ``--topics /cam0/image_raw,/imu0``). Samples: the header stamp (s),
``angular_velocity`` (rad/s) and ``linear_acceleration`` (m/s^2) of each message, sorted by stamp
and checked as an IMU file is (:func:`vslam.inertial.check_samples`: duplicate stamps, degrees, gaps).
Calibration (camera-IMU extrinsics, noise): a bag carries none; the files of
:data:`vslam.datasets.imu.IMU_CALIBRATION_NAMES` (Kalibr ``camchain-imucam.yaml`` / ``imu.yaml``,
EuRoC ``sensor.yaml``) in the ROS 2 bag folder, else beside the bag.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from vslam.errors import CalibrationError, DatasetError
from vslam.inertial import ImuCalibration, ImuMeasurements, check_samples

IMU_TYPE = "sensor_msgs/msg/Imu"


def split_imu_topics(topics, imu_topics) -> tuple[list[str] | None, str | None]:
    """``(image topic names or None, the requested IMU topic or None)`` of a ``--topics`` value."""
    if not topics:
        return None, None
    names = [t.strip() for t in (topics.split(",") if isinstance(topics, str) else topics) if t.strip()]
    imu = [n for n in names if n in imu_topics]
    if len(imu) > 1:
        raise DatasetError(f"--topics names {len(imu)} IMU topics ({', '.join(imu)}); name one")
    images = [n for n in names if n not in imu_topics]
    return images or None, imu[0] if imu else None


def choose_imu_topic(path: Path, imu_topics, requested: str | None) -> str:
    """The IMU topic to read: ``requested``, else the bag's only ``sensor_msgs/Imu`` topic."""
    if requested:
        return requested
    if len(imu_topics) == 1:
        return next(iter(imu_topics))
    if not imu_topics:
        raise DatasetError(f"{path}: the bag has no sensor_msgs/Imu topic; an inertial sensor needs one (or run "
                           "without -inertial)")
    raise DatasetError(f"{path}: cannot choose the IMU topic automatically ({', '.join(sorted(imu_topics))}); add "
                       "it to --topics")


def read_imu_topic(reader, connections, where: str) -> ImuMeasurements:
    """The samples of one Imu topic (module docstring); ``where`` names it in errors."""
    t, gyro, accel = [], [], []
    for conn, _t, raw in reader.messages(connections=connections):
        m = reader.deserialize(raw, conn.msgtype)
        st = m.header.stamp
        t.append(float(st.sec) + 1e-9 * float(st.nanosec))
        w, a = m.angular_velocity, m.linear_acceleration
        gyro.append((w.x, w.y, w.z))
        accel.append((a.x, a.y, a.z))
    if not t:
        raise DatasetError(f"{where}: no IMU messages")
    order = np.argsort(np.asarray(t), kind="stable")
    imu = ImuMeasurements(np.asarray(t)[order], np.asarray(gyro, float)[order], np.asarray(accel, float)[order],
                          source=where)
    check_samples(imu, where)
    return imu


def bag_imu_calibration(path: Path) -> ImuCalibration:
    """The IMU calibration files in the ROS 2 bag folder, else beside the bag (module docstring)."""
    from vslam.datasets.imu import IMU_CALIBRATION_NAMES, read_imu_calibration

    folders = [path, path.parent] if path.is_dir() else [path.parent]
    for folder in folders:
        found = [folder / n for n in IMU_CALIBRATION_NAMES if (folder / n).is_file()]
        if found:
            return read_imu_calibration(found)
    raise CalibrationError(f"{path}: no IMU calibration for the bag's IMU ({', '.join(IMU_CALIBRATION_NAMES)} in "
                           f"{' or '.join(map(str, folders))}); the camera-IMU extrinsics are needed, e.g. Kalibr's "
                           "camchain-imucam.yaml (cam0: T_cam_imu)")
