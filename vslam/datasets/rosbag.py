"""ROS 1 (``.bag``) and ROS 2 (folder with ``metadata.yaml``) bags, read with the pure-Python
``rosbags`` package (the ``ros`` extra; no ROS installation needed).

Topics: ``topics="COLOR[,DEPTH|,RIGHT]"``; when None they are chosen from the bag's
``sensor_msgs/Image`` and ``sensor_msgs/CompressedImage`` topics if that is unambiguous: one
colour topic, plus one topic named ``*depth*`` (RGB-D) or one named ``*right*`` (stereo). A second
topic given explicitly is depth when its name says ``depth`` or its encoding is ``16UC1`` /
``32FC1``, else the right image.

Messages: ``Image`` with ``rgb8``, ``bgr8``, ``rgba8``, ``bgra8``, ``mono8`` (colour), ``16UC1``
(depth in millimetres, as ROS does; ``depth_scale`` of a ``--camera`` file overrides) and
``32FC1`` (depth in metres); ``CompressedImage`` (PNG/JPEG, and ``compressedDepth``).
Timestamps are the message headers' stamps, which must increase in recording order on each image
topic (all equal, repeated or going back in time: a :class:`DatasetError` naming the topic, since
frames would collapse onto one timestamp). Depth and right images are paired with the colour
image of the nearest stamp (at most ``max_difference`` seconds apart).

Calibration: the ``camera`` argument (any format of :mod:`vslam.datasets.calibration`), else
the ``sensor_msgs/CameraInfo`` topic beside the colour topic (same namespace) in the bag. For
stereo, the right ``CameraInfo`` gives the baseline (``P[0, 3] = -fx * b``); images whose info has
distortion or a rectifying rotation are rectified with the info's ``R`` and ``P``.
Ground truth: a TUM-format ``groundtruth.txt`` in the ROS 2 bag folder, else beside the bag.
IMU (inertial sensors, read on first use): the ``sensor_msgs/Imu`` topic, :mod:`vslam.datasets.rosbag_imu`.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np

from vslam.datasets.base import CorruptFrameError, Dataset, interpolate_poses
from vslam.datasets.calib_checks import check_camera
from vslam.datasets.frame import Frame
from vslam.datasets.rosbag_imu import IMU_TYPE, bag_imu_calibration, choose_imu_topic, read_imu_topic, split_imu_topics
from vslam.errors import CalibrationError, DatasetError
from vslam.geometry.camera import PinholeCamera
from vslam.inertial import ImuCalibration, ImuMeasurements
from vslam.trajectory import associate_timestamps

log = logging.getLogger(__name__)

IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
INFO_TYPE = "sensor_msgs/msg/CameraInfo"
DEPTH_ENCODINGS = ("16UC1", "32FC1", "mono16")
ROS_DEPTH_SCALE = 1000.0  # 16UC1 depth is in millimetres


def is_bag(path: Path) -> bool:
    """A ROS 1 ``.bag`` file or a ROS 2 bag folder (``metadata.yaml``)."""
    return (path.is_file() and path.suffix == ".bag") or (path.is_dir() and (path / "metadata.yaml").is_file())


def _stamp(msg) -> float:
    st = msg.header.stamp
    return float(st.sec) + 1e-9 * float(st.nanosec)


def _check_stamps(path: Path, topic: str, stamps: np.ndarray) -> None:
    """Header stamps (in recording order) that are all equal, repeat or go back in time give no
    timing (frames would collapse onto one timestamp, or be reordered): a :class:`DatasetError`
    naming the bag and the topic."""
    if len(stamps) < 2:
        return
    d = np.diff(stamps)
    if np.all(d == 0):
        raise DatasetError(f"{path}: topic {topic}: all {len(stamps)} header stamps are {stamps[0]:.9f} s; the "
                           "messages carry no timing (the recording driver must set header.stamp)")
    if np.any(d <= 0):
        i = int(np.argmax(d <= 0)) + 1
        what = "repeats the stamp" if d[i - 1] == 0 else "goes back in time from"
        raise DatasetError(f"{path}: topic {topic}: header stamps are not increasing (message {i + 1}, stamped "
                           f"{stamps[i]:.9f} s, {what} message {i}, {stamps[i - 1]:.9f} s); fix the stamps of the "
                           "recording")


def decode_image(msg, msgtype: str) -> tuple[np.ndarray, str]:
    """``(array, encoding)`` of an Image / CompressedImage message; colour as BGR ``uint8``."""
    import cv2

    if msgtype.endswith("CompressedImage"):
        fmt = str(msg.format)
        buf = np.asarray(msg.data, dtype=np.uint8)
        if "compressedDepth" in fmt:
            buf = buf[12:]  # compressed_depth_image_transport's config header
        img = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED)
        if img is None:
            raise CorruptFrameError(f"a CompressedImage ({fmt}) cannot be decoded")
        if img.dtype == np.uint16:
            return img, "16UC1"
        if img.ndim == 3 and img.shape[2] == 4:
            img = cv2.cvtColor(img, cv2.COLOR_BGRA2BGR)
        return img, "bgr8" if img.ndim == 3 else "mono8"
    enc = str(msg.encoding)
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    data = np.asarray(msg.data, dtype=np.uint8)
    dtypes = {"rgb8": (np.uint8, 3), "bgr8": (np.uint8, 3), "rgba8": (np.uint8, 4), "bgra8": (np.uint8, 4),
              "mono8": (np.uint8, 1), "8UC1": (np.uint8, 1), "8UC3": (np.uint8, 3), "16UC1": (np.uint16, 1),
              "mono16": (np.uint16, 1), "32FC1": (np.float32, 1)}
    if enc not in dtypes:
        raise DatasetError(f"image encoding {enc!r} is not supported ({', '.join(dtypes)})")
    dt, ch = dtypes[enc]
    item = np.dtype(dt).itemsize
    if data.size < h * step or step < w * ch * item:
        raise CorruptFrameError(f"an Image message ({w}x{h} {enc}) has {data.size} bytes, expected {h * step}")
    rows = data[: h * step].reshape(h, step)[:, : w * ch * item]
    arr = rows.copy().view(np.dtype(dt).newbyteorder(">" if msg.is_bigendian else "<")).astype(dt)
    arr = arr.reshape(h, w, ch) if ch > 1 else arr.reshape(h, w)
    if enc == "rgb8":
        arr = arr[:, :, ::-1].copy()
    elif enc == "rgba8":
        arr = cv2.cvtColor(arr, cv2.COLOR_RGBA2BGR)
    elif enc == "bgra8":
        arr = cv2.cvtColor(arr, cv2.COLOR_BGRA2BGR)
    return arr, enc


def _info_camera(msg) -> tuple[PinholeCamera, np.ndarray, np.ndarray, str]:
    """``(camera with distortion, R (3, 3), P (3, 4), distortion model)`` of a CameraInfo."""
    get = lambda a, b: getattr(msg, a, None) if getattr(msg, a, None) is not None else getattr(msg, b)  # noqa: E731
    K = np.asarray(get("k", "K"), float).reshape(3, 3)
    D = [float(x) for x in get("d", "D")]
    R = np.asarray(get("r", "R"), float).reshape(3, 3)
    P = np.asarray(get("p", "P"), float).reshape(3, 4)
    model = str(msg.distortion_model or "plumb_bob")
    if model not in ("plumb_bob", "rational_polynomial", ""):
        raise CalibrationError(f"camera_info distortion model {model!r} is not supported here (plumb_bob); pass --camera")
    dist = tuple((D + [0.0] * 5)[:5])
    if K[0, 0] <= 0:
        raise CalibrationError("the bag's camera_info has no calibration (K is zero); pass --camera FILE")
    cam = PinholeCamera(K[0, 0], K[1, 1], K[0, 2], K[1, 2], int(msg.width), int(msg.height), dist)
    return cam, R, P, model


@dataclass
class _Topic:
    name: str
    msgtype: str
    connections: list


class RosbagDataset(Dataset):
    """Frames of one or two image topics of a ROS 1/2 bag."""

    kind = "rosbag"

    def __init__(
        self,
        path: str | Path,
        sensor: str | None = None,
        camera: PinholeCamera | str | Path | None = None,
        topics: str | list[str] | None = None,
        max_difference: float = 0.02,
    ) -> None:
        super().__init__()
        try:
            from rosbags.highlevel import AnyReader
            from rosbags.typesys import Stores, get_typestore
        except ImportError:  # pragma: no cover - the ros extra is missing
            raise DatasetError("reading ROS bags needs the 'rosbags' package: pip install 'vslam[ros]'") from None
        self.root = self.path = path = Path(path)
        if not is_bag(path):
            raise DatasetError(f"{path}: not a ROS bag (a .bag file or a ROS 2 folder with metadata.yaml)")
        self.name = path.stem if path.is_file() else path.name
        store = get_typestore(Stores.ROS1_NOETIC if path.suffix == ".bag" else Stores.ROS2_HUMBLE)
        self._reader_args = ([path], store)
        self._AnyReader = AnyReader
        reader = self._open()
        try:
            by_topic: dict[str, _Topic] = {}
            for c in reader.connections:
                t = by_topic.setdefault(c.topic, _Topic(c.topic, c.msgtype, []))
                t.connections.append(c)
            images = {k: v for k, v in by_topic.items() if v.msgtype in IMAGE_TYPES}
            infos = {k: v for k, v in by_topic.items() if v.msgtype == INFO_TYPE}
            self._imu_topics = {k: v for k, v in by_topic.items() if v.msgtype == IMU_TYPE}
            topics, self._imu_requested = split_imu_topics(topics, self._imu_topics)
            color, second = self._choose_topics(images, topics)
            self.topics = [color] + ([second] if second else [])
            color_idx = self._index(reader, images[color])
            self._second_kind = None
            second_idx = None
            if second:
                second_idx = self._index(reader, images[second])
                self._second_kind = self._kind_of(reader, images[second])
            self._images = images
            cam_info = self._camera_infos(reader, infos, color, second)
        finally:
            reader.close()

        if not color_idx[0].size:
            raise DatasetError(f"{path}: topic {color} has no messages")
        available = ["mono"]
        if self._second_kind == "depth":
            available.append("rgbd")
        elif self._second_kind == "right":
            available.append("stereo")
        self.sensors = tuple(available)
        self.sensor = self._select_sensor(sensor, available[-1], {
            "rgbd": "no depth topic (pass --topics COLOR,DEPTH)", "stereo": "no right topic (pass --topics LEFT,RIGHT)"})
        t_color, bag_color = color_idx
        if self.sensor == "mono":
            keep = np.arange(len(t_color))
            self._second = None
        else:
            t2, bag2 = second_idx
            pairs = np.column_stack(associate_timestamps(t_color, t2, max_difference if self.sensor == "rgbd" else 1e-3))
            if not len(pairs):
                raise DatasetError(f"{path}: no {second} message is within {max_difference} s of a {color} message")
            keep = pairs[:, 0]
            self._second = (t2[pairs[:, 1]], bag2[pairs[:, 1]])
        self._timestamps = t_color[keep]
        self._bag_ns = bag_color[keep]
        self._rectify = None
        self.T_cam0_rect = np.eye(4)  # frame camera -> the raw camera the calibration refers to
        self._depth_scale = ROS_DEPTH_SCALE
        self._setup_camera(camera, cam_info)
        span = self._timestamps[-1] - self._timestamps[0] if len(self._timestamps) > 1 else 0.0
        self.frame_rate = (len(self._timestamps) - 1) / span if span > 0 else 30.0
        # the bag's own folder first: a groundtruth.txt inside a ROS 2 bag folder wins over one beside it
        gt = [p / "groundtruth.txt" for p in (path, path.parent)] if path.is_dir() else [path.parent / "groundtruth.txt"]
        self._gt_file = next((g for g in gt if g.is_file()), None)
        self._imu: ImuMeasurements | None = None
        self._imu_calibration: ImuCalibration | None = None

    # -- IMU (lazy: a run without -inertial never reads it; vslam.datasets.rosbag_imu) -----------------
    @property
    def imu(self) -> ImuMeasurements | None:
        """The samples of the bag's ``sensor_msgs/Imu`` topic (read and checked on first use)."""
        if self._imu is None:
            from vslam.inertial import check_overlap

            topic = choose_imu_topic(self.path, self._imu_topics, self._imu_requested)
            reader = self._open()
            try:
                conns = [c for c in reader.connections if c.topic == topic]
                imu = read_imu_topic(reader, conns, f"{self.path}: topic {topic}")
            finally:
                reader.close()
            check_overlap(imu, float(self._timestamps[0]), float(self._timestamps[-1]), f"{self.path}: topic {topic}",
                          self.imu_calibration.time_offset)
            self._imu = imu
        return self._imu

    @property
    def imu_calibration(self) -> ImuCalibration | None:
        """From the calibration files in or beside the bag (:func:`bag_imu_calibration`); ``T_imu_cam`` of
        the raw camera (:func:`vslam.datasets.imu.dataset_imu` turns it to the frames' with ``T_cam0_rect``)."""
        if self._imu_calibration is None:
            self._imu_calibration = bag_imu_calibration(self.path)
        return self._imu_calibration

    # -- opening ---------------------------------------------------------------------------------
    def _open(self):
        paths, store = self._reader_args
        try:
            reader = self._AnyReader(paths, default_typestore=store)
            reader.open()
        except Exception as exc:  # rosbags raises its own errors for damaged bags
            raise DatasetError(f"{paths[0]}: cannot open the bag ({exc.__class__.__name__}: {exc})") from None
        return reader

    def _choose_topics(self, images: dict, topics) -> tuple[str, str | None]:
        listed = ", ".join(f"{k} ({v.msgtype.rsplit('/', 1)[-1]})" for k, v in sorted(images.items())) or "none"
        if topics:
            names = [t.strip() for t in (topics.split(",") if isinstance(topics, str) else topics) if t.strip()]
            if not 1 <= len(names) <= 2:
                raise DatasetError(f"--topics takes COLOR or COLOR,DEPTH or LEFT,RIGHT, got {topics!r}")
            for n in names:
                if n not in images:
                    raise DatasetError(f"{self.path}: no image topic {n!r}; image topics: {listed}")
            return names[0], names[1] if len(names) > 1 else None
        depth = [k for k in images if "depth" in k.lower()]
        right = [k for k in images if "right" in k.lower() and k not in depth]
        color = [k for k in images if k not in depth and k not in right]
        if not color and right and not depth:  # a stereo bag naming both sides: left + right
            color = [k for k in images if "left" in k.lower()]
        if len(color) != 1 or len(depth) > 1 or len(right) > 1 or (depth and right):
            raise DatasetError(
                f"{self.path}: cannot choose the image topics automatically; pass --topics COLOR[,DEPTH|,RIGHT] "
                f"(image topics: {listed})"
            )
        second = depth[0] if depth else (right[0] if right else None)
        return color[0], second

    def _index(self, reader, topic: _Topic) -> tuple[np.ndarray, np.ndarray]:
        """``(header stamps [s], bag times [ns])`` of a topic; the stamps must increase in recording
        order (:func:`_check_stamps`)."""
        stamps, bag = [], []
        for conn, t_ns, raw in reader.messages(connections=topic.connections):
            stamps.append(_stamp(reader.deserialize(raw, conn.msgtype)))
            bag.append(t_ns)
        _check_stamps(self.path, topic.name, np.asarray(stamps, float))
        order = np.argsort(np.asarray(stamps), kind="stable")
        return np.asarray(stamps, float)[order], np.asarray(bag, np.int64)[order]

    def _kind_of(self, reader, topic: _Topic) -> str:
        if "depth" in topic.name.lower():
            return "depth"
        for conn, _t, raw in reader.messages(connections=topic.connections):
            msg = reader.deserialize(raw, conn.msgtype)
            enc = str(getattr(msg, "encoding", getattr(msg, "format", "")))
            return "depth" if enc in DEPTH_ENCODINGS or "compressedDepth" in enc else "right"
        return "right"

    def _camera_infos(self, reader, infos: dict, color: str, second: str | None) -> dict:
        """The first CameraInfo message in the namespace of each chosen image topic."""
        out = {}
        for role, topic in (("color", color), ("second", second)):
            if topic is None:
                continue
            ns = topic.rsplit("/", 1)[0]
            cands = [k for k in infos if k.rsplit("/", 1)[0] == ns] or (
                [k for k in infos if k.startswith(ns.rsplit("/", 1)[0] + "/")] if role == "second" else [])
            if role == "color" and not cands and len(infos) == 1:
                cands = list(infos)
            if not cands:
                continue
            for conn, _t, raw in reader.messages(connections=infos[sorted(cands)[0]].connections):
                out[role] = reader.deserialize(raw, conn.msgtype)
                break
        return out

    def _setup_camera(self, camera, cam_info: dict) -> None:
        import cv2

        from vslam.datasets.calibration import Rectifier, read_camera_file

        if isinstance(camera, PinholeCamera):
            self.camera, self.calibration_source = camera, "the given camera"
            return
        if camera is not None:
            first = self._load_raw(0)[0]
            cal = read_camera_file(camera, (first.shape[1], first.shape[0]))
            if "depth_scale" in cal.extras:
                self._depth_scale = float(cal.extras["depth_scale"])
            self.calibration_source = cal.describe()
            if cal.needs_remap:
                if cal.right is not None and self.sensor != "stereo":
                    raise CalibrationError(f"{camera}: a stereo rig calibration for a {self.sensor} run")
                rect = Rectifier(cal)
                self.camera = rect.camera
                self.T_cam0_rect[:3, :3] = rect.R_rect_cam.T
                self._rectify = (rect.maps_left, rect.maps_right)
            else:
                self.camera = cal.camera
            return
        if "color" not in cam_info:
            raise CalibrationError(
                f"{self.path}: the bag has no sensor_msgs/CameraInfo for {self.topics[0]}; pass --camera FILE"
            )
        cam, R, P, _model = _info_camera(cam_info["color"])
        check_camera(cam, f"{self.path}: camera_info of {self.topics[0]}")
        self.calibration_source = f"camera_info in the bag ({self.path.name})"
        if self.sensor != "stereo":
            self.camera = cam
            return
        if "second" not in cam_info:
            raise CalibrationError(f"{self.path}: stereo needs the right camera_info in the bag, or pass --camera FILE")
        cam_r, R_r, P_r, _ = _info_camera(cam_info["second"])
        check_camera(cam_r, f"{self.path}: right camera_info")
        baseline = -P_r[0, 3] / P_r[0, 0]
        if not baseline > 0:
            raise CalibrationError(f"{self.path}: the right camera_info's P gives baseline {baseline}; P[0,3] must be -fx*b")
        raw = cam.is_distorted or cam_r.is_distorted or not np.allclose(R, np.eye(3)) or not np.allclose(R_r, np.eye(3))
        size = (cam.width, cam.height)
        if raw:
            self.T_cam0_rect[:3, :3] = R.T  # x_rect = R x_raw
            self._rectify = (
                cv2.initUndistortRectifyMap(cam.K, cam.dist_coeffs, R, P[:3, :3], size, cv2.CV_16SC2),
                cv2.initUndistortRectifyMap(cam_r.K, cam_r.dist_coeffs, R_r, P_r[:3, :3], size, cv2.CV_16SC2),
            )
        self.camera = PinholeCamera(P[0, 0], P[1, 1], P[0, 2], P[1, 2], cam.width, cam.height, baseline=float(baseline))

    # -- frames ----------------------------------------------------------------------------------
    def _load_raw(self, i: int) -> tuple[np.ndarray, np.ndarray | None]:
        """The colour (and second) image of frame ``i``, read by bag time."""
        reader = self._open()
        try:
            return self._read_at(reader, i)
        finally:
            reader.close()

    def _read_at(self, reader, i: int) -> tuple[np.ndarray, np.ndarray | None]:
        out = []
        specs = [(self.topics[0], int(self._bag_ns[i]))]
        if self._second is not None:
            specs.append((self.topics[1], int(self._second[1][i])))
        for topic, t_ns in specs:
            conns = [c for c in reader.connections if c.topic == topic]  # this reader's, not the indexing one's
            for conn, _t, raw in reader.messages(connections=conns, start=t_ns, stop=t_ns + 1):
                out.append(decode_image(reader.deserialize(raw, conn.msgtype), conn.msgtype)[0])
                break
            else:
                raise CorruptFrameError(f"{self.path}: message of {topic} at {t_ns} ns not found")
        return out[0], out[1] if len(out) > 1 else None

    def _frame(self, i: int, image: np.ndarray, second: np.ndarray | None) -> Frame:
        import cv2

        depth = right = None
        if second is not None and self.sensor == "rgbd":
            depth = second.astype(np.float32) if second.dtype == np.float32 else \
                second.astype(np.float32) / np.float32(self._depth_scale)
            depth[~np.isfinite(depth)] = 0.0
            if depth.shape != image.shape[:2]:
                raise DatasetError(f"{self.path}: depth is {depth.shape[::-1]} but the colour image {image.shape[1::-1]}")
        elif second is not None:
            right = second
        if self._rectify is not None:
            image = cv2.remap(image, *self._rectify[0], cv2.INTER_LINEAR)
            if depth is not None:
                depth = cv2.remap(depth, *self._rectify[0], cv2.INTER_NEAREST)
            if right is not None and self._rectify[1] is not None:
                right = cv2.remap(right, *self._rectify[1], cv2.INTER_LINEAR)
        self._check_size(image, self.path)
        return Frame(index=i, timestamp=float(self._timestamps[i]), image=image, camera=self.camera,
                     image_right=right, depth=depth, T_world_cam=self.gt_pose(i), path=f"{self.path}#{i}")

    def _load(self, i: int) -> Frame:
        return self._frame(i, *self._load_raw(i))

    def frames(self, start: int = 0, stop: int | None = None) -> Iterator[Frame]:
        """Read the bag once, in order (faster than seeking every frame)."""
        n = len(self)
        stop = n if stop is None else min(stop, n)
        if start >= stop:
            return
        reader = self._open()
        try:
            for i in range(max(start, 0), stop):
                yield self._frame(i, *self._read_at(reader, i))
        finally:
            reader.close()

    def _gt_poses(self):
        if self._gt_file is None:
            return None
        from vslam.trajectory import read_tum

        return interpolate_poses(read_tum(self._gt_file, duplicates="keep_last"), self._timestamps, max_gap=0.1)
