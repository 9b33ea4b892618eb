"""The IMU calibration: camera-IMU extrinsics, noise model, rate and time offset.

Noise model (Furgale / Kalibr "IMU noise model", as used by EuRoC's ``sensor.yaml``, Kalibr's
``imu.yaml`` and ORB-SLAM3's ``IMU.Noise*``): a measurement is ``y = x + b + n`` with white noise
``n`` of continuous-time density ``sigma`` (discrete std ``sigma / sqrt(dt)``) and a bias ``b``
driven by white noise of density ``sigma_b`` (discrete step std ``sigma_b * sqrt(dt)``).

Missing noise values take :data:`DEFAULT_NOISE` (the ADIS16448 of EuRoC's VI-sensor, from its
``imu0/sensor.yaml``) with a logged warning; see :func:`with_defaults`.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace

import numpy as np

from vslam.errors import CalibrationError
from vslam.geometry.lie import inv_se3

log = logging.getLogger(__name__)

#: Documented defaults for a missing noise value: EuRoC's ADIS16448 (``mav0/imu0/sensor.yaml``).
DEFAULT_NOISE: dict[str, float] = {
    "gyro_noise_density": 1.6968e-04,   # rad / s / sqrt(Hz)
    "gyro_random_walk": 1.9393e-05,     # rad / s^2 / sqrt(Hz)
    "accel_noise_density": 2.0e-03,     # m / s^2 / sqrt(Hz)
    "accel_random_walk": 3.0e-03,       # m / s^3 / sqrt(Hz)
}
#: Documented default rate when a file gives none (EuRoC, TUM-VI: 200 Hz).
DEFAULT_RATE_HZ = 200.0
#: Standard gravity, m/s^2 (GTSAM's CombinedImuFactorExample uses 9.81 too).
STANDARD_GRAVITY = 9.81
#: Tolerance of the rigidity check: ``|R^T R - I|_max`` and ``|det R - 1|`` (float32 files give ~1e-7).
RIGID_TOL = 1e-3


def check_rigid(T: np.ndarray, where: str, what: str = "T_imu_cam") -> np.ndarray:
    """``T`` as a float ``(4, 4)`` rigid transform, or :class:`CalibrationError` naming ``where``.

    Accepts 12 (3x4) or 16 numbers. Rejects a rotation block that is not orthonormal with
    determinant +1 (a scaled, sheared or mirrored matrix), a bad last row, or non-finite values.
    """
    try:
        a = np.asarray(T, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise CalibrationError(f"{where}: {what} is not a list of numbers") from None
    if a.size == 12:
        a = np.concatenate([a, [0.0, 0.0, 0.0, 1.0]])
    if a.size != 16:
        raise CalibrationError(f"{where}: {what} needs 16 numbers (a 4x4 matrix), got {a.size}")
    T = a.reshape(4, 4)
    if not np.all(np.isfinite(T)):
        raise CalibrationError(f"{where}: {what} has non-finite values")
    R = T[:3, :3]
    err = float(np.max(np.abs(R.T @ R - np.eye(3))))
    det = float(np.linalg.det(R))
    if not np.allclose(T[3], [0, 0, 0, 1]) or err > RIGID_TOL or abs(det - 1.0) > RIGID_TOL:
        raise CalibrationError(
            f"{where}: {what} is not a rigid transform (|R^T R - I| = {err:.2g}, det R = {det:.4f}, last row "
            f"{T[3].tolist()}); it must be a rotation (orthonormal, det +1) and a translation, last row 0 0 0 1"
        )
    return T


@dataclass(frozen=True)
class ImuCalibration:
    """Camera-IMU calibration.

    Attributes:
        T_imu_cam: ``(4, 4)`` camera -> IMU (EuRoC's cam0 ``T_BS`` when the body is the IMU;
            Kalibr ``inv(T_cam_imu)``; ORB-SLAM3 ``IMU.T_b_c1``).
        gyro_noise_density: rad/s/sqrt(Hz). gyro_random_walk: rad/s^2/sqrt(Hz).
        accel_noise_density: m/s^2/sqrt(Hz). accel_random_walk: m/s^3/sqrt(Hz).
        rate_hz: nominal sample rate.
        time_offset: seconds, Kalibr's ``timeshift_cam_imu``: ``t_imu = t_cam + time_offset``.
        gravity: magnitude of gravity, m/s^2.
        defaulted: names of the fields that took a documented default.
        source: the file(s) it was read from.
    """

    T_imu_cam: np.ndarray
    gyro_noise_density: float = DEFAULT_NOISE["gyro_noise_density"]
    gyro_random_walk: float = DEFAULT_NOISE["gyro_random_walk"]
    accel_noise_density: float = DEFAULT_NOISE["accel_noise_density"]
    accel_random_walk: float = DEFAULT_NOISE["accel_random_walk"]
    rate_hz: float = DEFAULT_RATE_HZ
    time_offset: float = 0.0
    gravity: float = STANDARD_GRAVITY
    defaulted: tuple[str, ...] = field(default=())
    source: str = ""

    def __post_init__(self) -> None:
        object.__setattr__(self, "T_imu_cam", check_rigid(self.T_imu_cam, self.source or "IMU calibration"))
        for name in ("gyro_noise_density", "gyro_random_walk", "accel_noise_density", "accel_random_walk",
                     "rate_hz", "gravity"):
            v = float(getattr(self, name))
            if not np.isfinite(v) or v <= 0:
                raise CalibrationError(f"{self.source or 'IMU calibration'}: {name} must be a positive number, got {v}")
            object.__setattr__(self, name, v)
        if not np.isfinite(self.time_offset):
            raise CalibrationError(f"{self.source or 'IMU calibration'}: time_offset must be finite")

    @property
    def T_cam_imu(self) -> np.ndarray:
        """IMU -> camera (Kalibr's ``T_cam_imu``)."""
        return inv_se3(self.T_imu_cam)

    def imu_time(self, t_cam: float | np.ndarray) -> float | np.ndarray:
        """A camera timestamp on the IMU clock: ``t_cam + time_offset``."""
        return t_cam + self.time_offset

    def with_camera(self, T_cam_newcam: np.ndarray) -> "ImuCalibration":
        """The same IMU seen from another camera frame rigidly attached to this one (e.g. the
        rectified left camera of a stereo rig: ``T_cam0_rect = [R1^T | 0]``)."""
        return replace(self, T_imu_cam=self.T_imu_cam @ np.asarray(T_cam_newcam, float))


def with_defaults(values: dict, where: str) -> dict:
    """``values`` with each missing noise value / rate filled from the documented defaults
    (:data:`DEFAULT_NOISE`, :data:`DEFAULT_RATE_HZ`), one logged warning listing them; the filled
    names are returned under ``"defaulted"``."""
    out = dict(values)
    missing = [k for k in DEFAULT_NOISE if out.get(k) is None]
    for k in missing:
        out[k] = DEFAULT_NOISE[k]
    if out.get("rate_hz") is None:
        out["rate_hz"] = DEFAULT_RATE_HZ
        missing.append("rate_hz")
    if missing:
        log.warning(
            "%s: no %s given; using the documented defaults (EuRoC ADIS16448: %s)", where, ", ".join(missing),
            ", ".join(f"{k}={DEFAULT_NOISE[k]:g}" if k in DEFAULT_NOISE else f"{k}={DEFAULT_RATE_HZ:g}" for k in missing),
        )
    out["defaulted"] = tuple(missing)
    return out
