"""EuRoC MAV sequences in the ASL layout (Burri et al., IJRR 2016).

``mav0/cam0|cam1/{data.csv, data/<ns>.png, sensor.yaml}``; ``sensor.yaml`` holds the pinhole
intrinsics ``[fu, fv, cu, cv]``, radtan distortion ``[k1, k2, p1, p2]``, the resolution and
``T_BS`` (camera -> body).

* ``stereo`` (default): both images are rectified to an ideal pinhole pair with
  ``cv2.stereoRectify`` (zero disparity at infinity, ``alpha=0``: no invalid borders) and
  ``cv2.initUndistortRectifyMap``, computed once at open and applied with ``cv2.remap`` per frame.
  The frame camera is the rectified left camera (``P1[:, :3]``, no distortion) with the baseline
  ``-P2[0, 3] / P2[0, 0]`` (~0.110 m). Ground truth is of the rectified left camera:
  ``T_world_rect = T_world_cam0 * [R1^T | 0]``.
* ``mono``: the raw, distorted cam0 image with the distorted cam0 camera (``dist`` set: undistort
  keypoints with :meth:`PinholeCamera.undistort_points`); ground truth ``T_world_cam0``.

Ground truth, first found: ``groundtruth_cam0_tum.txt`` (TUM, already ``T_world_cam0``) beside
``mav0``; ``mav0/state_groundtruth_estimate0/data.csv`` (body poses, converted with cam0's
``T_BS``: ``T_world_cam0 = T_world_body * T_BS``); an ORB-SLAM3 ``*_GT_left_cam.txt`` (ns CSV of
cam0 positions whose quaternion is stored conjugated, i.e. ``R_cam_world``). GT is interpolated to
the image timestamps (SLERP, max gap 0.1 s).

IMU (read lazily, on first use, so a non-inertial run never reads it): ``mav0/imu0/data.csv`` is
:attr:`EurocDataset.imu` (:class:`vslam.inertial.ImuMeasurements`, checked, and checked to overlap
the images) and ``mav0/imu0/sensor.yaml`` with cam0's ``T_BS`` is :attr:`EurocDataset.imu_calibration`
(``T_imu_cam`` of the raw cam0; for rectified stereo frames use
``imu_calibration.with_camera(T_cam0_rect)``, :attr:`EurocDataset.T_cam0_rect`). Both are None
without ``imu0/data.csv``.
"""
from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from vslam.datasets.base import (
    Dataset,
    interpolate_poses,
    load_image,
    require_dir,
    require_file,
)
from vslam.datasets.camera_yaml import load_yaml
from vslam.datasets.frame import Frame
from vslam.datasets.imu import euroc_imu_calibration, load_imu_csv
from vslam.errors import CalibrationError, DatasetError, TrajectoryError
from vslam.textfile import open_text
from vslam.trajectory import Trajectory, read_euroc, read_tum
from vslam.geometry.camera import PinholeCamera
from vslam.geometry.lie import inv_se3
from vslam.inertial import ImuCalibration, ImuMeasurements, check_overlap

log = logging.getLogger(__name__)


def read_euroc_sensor(path: str | Path) -> tuple[PinholeCamera, np.ndarray, float]:
    """Parse a camera ``sensor.yaml`` -> ``(distorted camera, T_body_cam (4, 4), rate_hz)``."""
    path = Path(path)
    if not path.is_file():
        raise CalibrationError(f"{path}: EuRoC camera sensor.yaml not found")
    data = load_yaml(path)
    try:
        fu, fv, cu, cv = (float(v) for v in data["intrinsics"])
        w, h = (int(v) for v in data["resolution"])
        dist = [float(v) for v in data.get("distortion_coefficients", [0, 0, 0, 0])]
        T = np.array(data["T_BS"]["data"], dtype=float).reshape(4, 4)
    except KeyError as exc:
        raise CalibrationError(
            f"{path}: missing {exc.args[0]!r}; sensor.yaml needs intrinsics, resolution, "
            f"distortion_coefficients and T_BS"
        ) from None
    except (TypeError, ValueError):
        raise CalibrationError(
            f"{path}: malformed values: intrinsics must be [fu, fv, cu, cv], resolution [w, h], T_BS 16 numbers"
        ) from None
    model = data.get("distortion_model", "radial-tangential")
    if model not in ("radial-tangential", "radtan", "plumb_bob"):
        raise CalibrationError(f"{path}: distortion model {model!r} is not supported (use radial-tangential)")
    if len(dist) not in (4, 5):
        raise CalibrationError(f"{path}: distortion_coefficients needs 4 numbers [k1, k2, p1, p2]")
    if not np.allclose(T[3], [0, 0, 0, 1]) or not np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-4):
        raise CalibrationError(f"{path}: T_BS is not a rigid transform (rotation not orthonormal)")
    cam = PinholeCamera(fu, fv, cu, cv, w, h, tuple(dist + [0.0] * (5 - len(dist))))
    return cam, T, float(data.get("rate_hz", 20.0))


def _read_cam_csv(csv: Path, what: str) -> tuple[np.ndarray, list[str]]:
    csv = require_file(csv, f"EuRoC {what} list")
    ns, names = [], []
    with open_text(csv, DatasetError) as fh:
        for lineno, line in enumerate(fh, 1):
            line = line.strip()
            if not line or line.startswith("#"):
                continue
            parts = [p.strip() for p in line.split(",")]
            if len(parts) < 2:
                raise DatasetError(f"{csv}:{lineno}: expected 'timestamp_ns,filename', got {line[:80]!r}")
            try:
                ns.append(int(parts[0]))
            except ValueError:
                raise DatasetError(f"{csv}:{lineno}: timestamp {parts[0]!r} is not an integer (ns)") from None
            names.append(parts[1])
    if not ns:
        raise DatasetError(f"{csv}: lists no images")
    arr = np.array(ns, dtype=np.int64)
    _check_ns(arr, csv)
    return arr, names


def _check_ns(ns: np.ndarray, path: Path) -> None:
    d = np.diff(ns)
    if np.any(d == 0):
        i = int(np.argmax(d == 0))
        raise DatasetError(f"{path}: duplicate timestamp {ns[i]} (entries {i + 1} and {i + 2}); remove one")
    if np.any(d < 0):
        i = int(np.argmax(d < 0))
        raise DatasetError(f"{path}: timestamps are not sorted (entry {i + 2} goes back in time); sort the file")


class EurocDataset(Dataset):
    """A EuRoC ASL sequence (the folder holding ``mav0``, or ``mav0`` itself)."""

    kind = "euroc"

    def __init__(self, path: str | Path, sensor: str | None = None, gt_max_gap: float = 0.1) -> None:
        super().__init__()
        path = require_dir(path, "EuRoC sequence folder")
        mav0 = path / "mav0" if (path / "mav0").is_dir() else path
        self.root = path if mav0 != path else path.parent
        self.mav0 = mav0
        self.name = self.root.name
        cam0_dir, cam1_dir = mav0 / "cam0", mav0 / "cam1"
        if not cam0_dir.is_dir():
            raise DatasetError(f"{cam0_dir}: not found; an EuRoC sequence needs mav0/cam0/")
        ns0, names0 = _read_cam_csv(cam0_dir / "data.csv", "cam0")
        self.cam0, self.T_body_cam0, rate = read_euroc_sensor(cam0_dir / "sensor.yaml")
        has_cam1 = (cam1_dir / "data.csv").is_file()
        self.sensors = ("mono", "stereo") if has_cam1 else ("mono",)
        self.sensor = self._select_sensor(sensor, "stereo" if has_cam1 else "mono", {
            "stereo": f"no {cam1_dir / 'data.csv'}", "rgbd": "EuRoC has no depth images",
        })
        self.frame_rate = rate
        self._gt_max_gap = gt_max_gap
        self._R_cam0_rect = np.eye(3)
        if self.sensor == "stereo":
            ns1, names1 = _read_cam_csv(cam1_dir / "data.csv", "cam1")
            common, i0, i1 = np.intersect1d(ns0, ns1, assume_unique=True, return_indices=True)
            if len(common) == 0:
                raise DatasetError(f"{cam1_dir / 'data.csv'}: no timestamp matches one of {cam0_dir / 'data.csv'}")
            if len(common) < len(ns0):
                log.info("%s: %d cam0 images have no cam1 partner and are left out", self.root, len(ns0) - len(common))
            self._ns = common
            self._left = [cam0_dir / "data" / names0[i] for i in i0]
            self._right = [cam1_dir / "data" / names1[i] for i in i1]
            self.cam1, self.T_body_cam1, _ = read_euroc_sensor(cam1_dir / "sensor.yaml")
            self._rectify()
        else:
            self._ns = ns0
            self._left = [cam0_dir / "data" / n for n in names0]
            self._right = None
            self.camera = self.cam0
        self._timestamps = self._ns.astype(np.float64) * 1e-9
        missing = [p for p in self._left if not p.is_file()]
        if missing and (not self._left[0].is_file() or len(missing) > 0.1 * len(self._left)):
            raise DatasetError(f"{missing[0]}: {len(missing)} of {len(self._left)} listed images are missing")
        self.imu_path: Path | None = mav0 / "imu0" / "data.csv" if (mav0 / "imu0" / "data.csv").is_file() else None
        self._imu: ImuMeasurements | None = None
        self._imu_calibration: ImuCalibration | None = None

    # -- IMU (lazy) -------------------------------------------------------------------------------
    @property
    def imu(self) -> ImuMeasurements | None:
        """The ``mav0/imu0/data.csv`` samples (read and checked on first use), or None."""
        if self._imu is None and self.imu_path is not None:
            imu = load_imu_csv(self.imu_path)
            calib = self.imu_calibration
            check_overlap(imu, float(self._timestamps[0]), float(self._timestamps[-1]), str(self.imu_path),
                          calib.time_offset if calib is not None else 0.0)
            self._imu = imu
        return self._imu

    @property
    def imu_calibration(self) -> ImuCalibration | None:
        """``imu0/sensor.yaml`` noise values and cam0's ``T_BS`` as ``T_imu_cam``, or None without an IMU."""
        if self._imu_calibration is None and self.imu_path is not None:
            self._imu_calibration = euroc_imu_calibration(self.imu_path.parent / "sensor.yaml", self.T_body_cam0)
        return self._imu_calibration

    @property
    def T_cam0_rect(self) -> np.ndarray:
        """``(4, 4)`` frame camera -> raw cam0 (the rectifying rotation for stereo, identity for mono)."""
        T = np.eye(4)
        T[:3, :3] = self._R_cam0_rect
        return T

    def _rectify(self) -> None:
        """Stereo rectification (Bouguet, via ``cv2.stereoRectify``) and the remap tables."""
        import cv2

        c0, c1 = self.cam0, self.cam1
        if (c0.width, c0.height) != (c1.width, c1.height):
            raise CalibrationError(f"{self.mav0}: cam0 and cam1 have different resolutions")
        T_cam1_cam0 = inv_se3(self.T_body_cam1) @ self.T_body_cam0
        size = (c0.width, c0.height)
        R1, R2, P1, P2, _Q, _r1, _r2 = cv2.stereoRectify(
            c0.K, c0.dist_coeffs, c1.K, c1.dist_coeffs, size,
            T_cam1_cam0[:3, :3], T_cam1_cam0[:3, 3], flags=cv2.CALIB_ZERO_DISPARITY, alpha=0,
        )
        self._maps = (
            cv2.initUndistortRectifyMap(c0.K, c0.dist_coeffs, R1, P1, size, cv2.CV_16SC2),
            cv2.initUndistortRectifyMap(c1.K, c1.dist_coeffs, R2, P2, size, cv2.CV_16SC2),
        )
        baseline = float(-P2[0, 3] / P2[0, 0])
        if not baseline > 0:
            raise CalibrationError(f"{self.mav0}: rectification gave baseline {baseline}; check the T_BS of cam0/cam1")
        self.R_rect_cam0 = R1
        self._R_cam0_rect = R1.T
        self.camera = PinholeCamera(
            float(P1[0, 0]), float(P1[1, 1]), float(P1[0, 2]), float(P1[1, 2]), c0.width, c0.height, baseline=baseline
        )

    # ------------------------------------------------------------------------------------------
    def _read_gt_cam0(self) -> Trajectory | None:
        try:
            tum = self.root / "groundtruth_cam0_tum.txt"
            if tum.is_file():
                return read_tum(tum)
            body = self.mav0 / "state_groundtruth_estimate0" / "data.csv"
            if body.is_file():
                gt = read_euroc(body)
                return Trajectory(gt.timestamps, gt.T_world_cam @ self.T_body_cam0)
            orb = sorted(self.root.glob("*_GT_left_cam.txt")) + sorted(self.root.glob("*_GT.txt"))
            if orb:
                gt = read_euroc(orb[0])
                T = gt.T_world_cam.copy()
                T[:, :3, :3] = np.transpose(T[:, :3, :3], (0, 2, 1))  # stored quaternion is R_cam_world
                return Trajectory(gt.timestamps, T)
        except TrajectoryError as exc:
            raise DatasetError(str(exc)) from None
        return None

    def _gt_poses(self):
        gt = self._read_gt_cam0()
        if gt is None:
            return None
        T, valid = interpolate_poses(gt, self._timestamps, max_gap=self._gt_max_gap)
        T_cam0_rect = np.eye(4)
        T_cam0_rect[:3, :3] = self._R_cam0_rect
        T[valid] = T[valid] @ T_cam0_rect
        return T, valid

    def _load(self, i: int) -> Frame:
        import cv2

        path = self._left[i]
        image = load_image(path, grayscale=True)
        self._check_size(image, path)
        right = None
        if self._right is not None:
            right = load_image(self._right[i], grayscale=True)
            self._check_size(right, self._right[i])
            (m0x, m0y), (m1x, m1y) = self._maps
            image = cv2.remap(image, m0x, m0y, cv2.INTER_LINEAR)
            right = cv2.remap(right, m1x, m1y, cv2.INTER_LINEAR)
        return Frame(
            index=i, timestamp=float(self._timestamps[i]), image=image, camera=self.camera,
            image_right=right, T_world_cam=self.gt_pose(i), path=str(path),
        )
