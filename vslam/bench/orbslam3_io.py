"""Files of the ORB-SLAM3 baseline's child (:mod:`vslam.bench.orbslam3_baseline`): the settings
YAML (:func:`settings_yaml`), ORB-SLAM3's saved EuRoC trajectory (:func:`read_euroc_ns`), and the
inertial sensors: ``mono-inertial``, ``stereo-inertial`` and ``rgbd-inertial`` run as ORB-SLAM3's
``IMU_MONOCULAR``, ``IMU_STEREO`` and ``IMU_RGBD``.

What ``pyorbslam3`` 0.1.1 offers (and this module uses):

* ``Sensor.IMU_MONOCULAR`` / ``IMU_STEREO`` / ``IMU_RGBD``; every ``track_*`` call of an IMU mode
  takes ``imu=``, an ``(N, 7)`` array of rows ``[t, gx, gy, gz, ax, ay, az]`` (s, rad/s, m/s^2):
  the samples with ``t`` in ``(previous frame time, this frame time]`` (:class:`ImuFeeder`; the
  first frame gets the last sample at or before it, as ORB-SLAM3's EuRoC examples do);
* the settings file's IMU block (:func:`imu_settings_lines`): the settings are in the older key
  form, whose loader (``Tracking::ParseIMUParamFile``) reads the body-camera extrinsics as ``Tbc``
  (an ``!!opencv-matrix``; the v1.0 form's ``IMU.T_b_c1`` is written too, for a reader of the
  file) and ``IMU.NoiseGyro``, ``IMU.NoiseAcc``, ``IMU.GyroWalk``, ``IMU.AccWalk``,
  ``IMU.Frequency``: vslam's :class:`~vslam.inertial.ImuCalibration` maps one to one (the same
  Furgale noise model, continuous-time densities);
* ``save_trajectory_euroc`` after ``shutdown()``: in an IMU mode ORB-SLAM3 writes the **IMU (body)**
  pose ``T_world_body`` of every frame, not the camera's; :func:`body_to_camera` turns it into
  vslam's ``T_world_cam`` of the frames' camera (the rectified left camera of EuRoC stereo:
  ``T_imu_cam`` comes from :func:`vslam.datasets.imu.dataset_imu`, which applies ``T_cam0_rect``).
  The online poses (``TrackResult.pose_wc``) from before ORB-SLAM3's IMU initialization are in the
  map's first, not gravity-aligned frame (and, monocular, at another scale): only those from
  after it are kept, as the fallback when the saved file is empty.

The IMU clock is moved onto the camera clock with the calibration's ``time_offset``
(``t_imu = t_cam + time_offset``, zero for EuRoC).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from vslam.errors import VslamError

#: vslam's inertial sensor -> the name of pyorbslam3's ``Sensor`` member
ORB_SENSORS = {"mono": "MONOCULAR", "stereo": "STEREO", "rgbd": "RGBD", "mono-inertial": "IMU_MONOCULAR",
               "stereo-inertial": "IMU_STEREO", "rgbd-inertial": "IMU_RGBD"}


def orb_sensor(orb: Any, sensor: str) -> Any:
    """pyorbslam3's ``Sensor`` member for vslam's ``sensor``; a wheel without the IMU modes is one
    :class:`VslamError` (the baseline never runs an inertial sensor as a visual-only one)."""
    name = ORB_SENSORS[sensor]
    member = getattr(orb.Sensor, name, None)
    if member is None:
        raise VslamError(f"this pyorbslam3 ({getattr(orb, '__version__', 'unknown version')}) has no Sensor.{name}: "
                         f"it cannot run ORB-SLAM3 as {sensor}; install pyorbslam3==0.1.1")
    return member


def _opencv_matrix(name: str, T: np.ndarray) -> list[str]:
    data = ", ".join(f"{v:.9f}" for v in np.asarray(T, float).ravel())
    return [f"{name}: !!opencv-matrix", "   rows: 4", "   cols: 4", "   dt: f", f"   data: [{data}]"]


def imu_settings_lines(calib: Any) -> list[str]:
    """The settings lines of the IMU (``calib``: a :class:`~vslam.inertial.ImuCalibration` whose
    ``T_imu_cam`` refers to the frames' camera)."""
    T_b_c = np.asarray(calib.T_imu_cam, float)
    return (_opencv_matrix("Tbc", T_b_c) + _opencv_matrix("IMU.T_b_c1", T_b_c)
            + [f"IMU.NoiseGyro: {calib.gyro_noise_density:.6e}", f"IMU.NoiseAcc: {calib.accel_noise_density:.6e}",
               f"IMU.GyroWalk: {calib.gyro_random_walk:.6e}", f"IMU.AccWalk: {calib.accel_random_walk:.6e}",
               f"IMU.Frequency: {max(1, int(round(calib.rate_hz)))}", "IMU.InsertKFsWhenLost: 1"])


class ImuFeeder:
    """Hands each frame the IMU samples ORB-SLAM3 expects with it, as ``(N, 7)`` rows
    ``[t, gx, gy, gz, ax, ay, az]`` on the camera clock.

    Example:
        >>> from vslam.inertial import ImuMeasurements
        >>> t = np.arange(10) * 0.005
        >>> feed = ImuFeeder(ImuMeasurements(t, np.zeros((10, 3)), np.zeros((10, 3))))
        >>> [len(feed.chunk(x)) for x in (0.012, 0.021, 0.031, 0.031)]
        [1, 2, 2, 0]
    """

    def __init__(self, imu: Any, time_offset: float = 0.0) -> None:
        t = np.asarray(imu.timestamps, float) - float(time_offset)
        self.rows = np.column_stack([t, np.asarray(imu.gyro, float), np.asarray(imu.accel, float)])
        self._t = t
        self._next: int | None = None
        self.fed = 0

    def chunk(self, t_frame: float) -> np.ndarray:
        """The samples for the frame at ``t_frame`` (frames in time order)."""
        end = int(np.searchsorted(self._t, t_frame, side="right"))
        start = max(0, end - 1) if self._next is None else min(self._next, end)
        self._next = max(end, self._next or 0)
        self.fed += end - start
        return self.rows[start:end]


def body_to_camera(traj: Any, T_imu_cam: np.ndarray) -> Any:
    """ORB-SLAM3's saved ``T_world_body`` trajectory of an IMU mode as ``T_world_cam``."""
    from vslam.trajectory import Trajectory

    return Trajectory(traj.timestamps, np.asarray(traj.T_world_cam, float) @ np.asarray(T_imu_cam, float))


def imu_for(ds: Any) -> tuple[Any, Any]:
    """``(samples, calibration)`` of the sequence's IMU for the frames' camera (EuRoC stereo: the
    rectified left camera), as a vslam inertial run reads them."""
    from vslam.datasets.imu import dataset_imu

    return dataset_imu(ds)


def settings_yaml(camera: Any, sensor: str, frame_rate: float, depth_scale: float = 1.0,
                  imu_calibration: Any = None) -> str:
    """ORB-SLAM3 settings in the older ``Camera.*`` form (see the pitfalls in :mod:`vslam.bench.orbslam3_baseline`); ``sensor`` is the
    visual base sensor, ``imu_calibration`` adds the IMU block of an inertial mode
    (:func:`imu_settings_lines`).

    ORB parameters follow ORB-SLAM3's example settings: 2000 features for KITTI-sized images
    (> 400k pixels), 1000 for 640x480; stereo/RGB-D ``ThDepth`` 40 baselines (KITTI uses 35).
    """
    dist = np.zeros(5) if camera.dist is None else np.asarray(camera.dist, float).ravel()
    dist = np.pad(dist, (0, max(0, 5 - len(dist))))[:5]
    n_features = 2000 if camera.width * camera.height > 400_000 else 1000
    lines = [
        "%YAML:1.0", "Camera.type: \"PinHole\"",
        f"Camera.fx: {camera.fx}", f"Camera.fy: {camera.fy}", f"Camera.cx: {camera.cx}", f"Camera.cy: {camera.cy}",
        f"Camera.k1: {dist[0]}", f"Camera.k2: {dist[1]}", f"Camera.p1: {dist[2]}", f"Camera.p2: {dist[3]}",
        f"Camera.k3: {dist[4]}",
        f"Camera.width: {camera.width}", f"Camera.height: {camera.height}",
        f"Camera.fps: {max(1, int(round(frame_rate)))}", "Camera.RGB: 0",
        f"ORBextractor.nFeatures: {n_features}", "ORBextractor.scaleFactor: 1.2", "ORBextractor.nLevels: 8",
        "ORBextractor.iniThFAST: 20", "ORBextractor.minThFAST: 7",
        "Viewer.KeyFrameSize: 0.05", "Viewer.KeyFrameLineWidth: 1.0", "Viewer.GraphLineWidth: 0.9",
        "Viewer.PointSize: 2.0", "Viewer.CameraSize: 0.08", "Viewer.CameraLineWidth: 3.0",
        "Viewer.ViewpointX: 0.0", "Viewer.ViewpointY: -0.7", "Viewer.ViewpointZ: -1.8", "Viewer.ViewpointF: 500.0",
    ]
    if sensor in ("stereo", "rgbd"):
        baseline = float(camera.baseline or 0.0)
        lines += [f"Camera.bf: {camera.fx * baseline if sensor == 'stereo' else camera.fx * 0.08}",
                  "ThDepth: 40.0"]
    if sensor == "rgbd":
        lines.append(f"DepthMapFactor: {depth_scale}")  # frames carry depth in metres already
    if imu_calibration is not None:
        lines += imu_settings_lines(imu_calibration)
    return "\n".join(lines) + "\n"


def read_euroc_ns(path: str | Path):
    """ORB-SLAM3's ``SaveTrajectoryEuRoC`` file (``t_ns tx ty tz qx qy qz qw``, spaces) as a
    :class:`~vslam.trajectory.Trajectory` in seconds; None when missing or empty.

    ORB-SLAM3 repeats the last frame's time and pose for every frame it lost: only the first line
    of each timestamp is kept, so lost frames do not count as poses.
    """
    from scipy.spatial.transform import Rotation

    from vslam.trajectory import Trajectory

    path = Path(path)
    if not path.is_file() or path.stat().st_size == 0:
        return None
    data = np.loadtxt(path, ndmin=2)
    if data.shape[0] == 0 or data.shape[1] != 8:
        return None
    _, first = np.unique(data[:, 0], return_index=True)  # sorted by time, first of equal times
    data = data[first]
    T = np.tile(np.eye(4), (len(data), 1, 1))
    T[:, :3, :3] = Rotation.from_quat(data[:, 4:8]).as_matrix()
    T[:, :3, 3] = data[:, 1:4]
    return Trajectory(data[:, 0] * 1e-9, T)
