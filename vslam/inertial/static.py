"""Gravity and IMU biases from an interval at rest (the classic static initialization, e.g.
ORB-SLAM3's and VINS-Mono's stationary start; Forster et al. 2017 sec. VII discusses observability).

At rest the gyro reads its bias (Earth rotation, 7.3e-5 rad/s, is below the noise of MEMS gyros
and ignored) and the accelerometer reads ``R_imu_world (0, 0, g) + b_a``: the mean of each over the
interval gives the gyro bias and, without an attitude, the gravity direction in the IMU frame with
only the component of ``b_a`` along gravity observable (``|mean a| - g``). With a known attitude
``R_world_imu`` (ground truth, or an external reference) all of ``b_a`` is.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from vslam.errors import DatasetError
from vslam.geometry.lie import so3_exp
from vslam.inertial.calibration import STANDARD_GRAVITY
from vslam.inertial.checks import smoothed_std
from vslam.inertial.measurements import ImuMeasurements

log = logging.getLogger(__name__)

#: Largest per-axis std (m/s^2) of the accelerometer's 0.1 s means still called "at rest"
#: (:func:`vslam.inertial.checks.smoothed_std`; EuRoC V1_01 at rest with its motors on: <= 0.10,
#: hand-held MH_01: >= 0.3).
REST_ACCEL_STD = 0.15


@dataclass(frozen=True)
class StaticEstimate:
    """What an interval at rest tells.

    Attributes:
        gyro_bias: ``(3,)`` rad/s (mean gyro).
        gravity_imu: ``(3,)`` unit vector of gravity (pointing down) in the IMU frame.
        accel_bias: ``(3,)`` m/s^2: with an attitude, all of it; without, only its component along
            gravity, ``(|mean a| - g) * up``.
        accel_mean: ``(3,)`` mean accelerometer reading.
        accel_std, gyro_std: ``(3,)`` per-axis standard deviations over the interval.
        n: number of samples.
    """

    gyro_bias: np.ndarray
    gravity_imu: np.ndarray
    accel_bias: np.ndarray
    accel_mean: np.ndarray
    accel_std: np.ndarray
    gyro_std: np.ndarray
    n: int

    @property
    def R_world_imu(self) -> np.ndarray:
        """An attitude putting the measured gravity on ``-z`` of a z-up world (yaw arbitrary: the
        smallest rotation taking the measured ``up`` to ``+z``)."""
        return rotation_to_up(-self.gravity_imu)


def rotation_to_up(up: np.ndarray) -> np.ndarray:
    """The smallest rotation ``R`` with ``R up = +z`` for a unit vector ``up`` (yaw-free: the
    rotation about ``up x z``); its transpose takes ``+z`` to ``up``."""
    up = np.asarray(up, float)
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(up, z)
    s, c = float(np.linalg.norm(axis)), float(up @ z)
    if s < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    return so3_exp(axis / s * np.arctan2(s, c))


def estimate_static(imu: ImuMeasurements, t0: float | None = None, t1: float | None = None,
                    R_world_imu: np.ndarray | None = None, gravity: float = STANDARD_GRAVITY) -> StaticEstimate:
    """Gyro bias, gravity direction and accelerometer bias from the samples in ``[t0, t1]``
    (default: all), which must be at rest.

    ``R_world_imu`` (``(3, 3)``, a z-up world; one attitude for the interval) makes the whole
    accelerometer bias observable: ``b_a = mean(a) - R_world_imu^T (0, 0, g)``. An interval whose
    accelerometer varies more than :data:`REST_ACCEL_STD` gives a warning (the estimate assumes rest).
    """
    seg = imu.between(-np.inf if t0 is None else t0, np.inf if t1 is None else t1)
    if len(seg) < 10:
        raise DatasetError(f"{imu.source or 'IMU'}: {len(seg)} samples in the rest interval; need at least 10")
    a_mean, w_mean = seg.accel.mean(axis=0), seg.gyro.mean(axis=0)
    a_std, w_std = seg.accel.std(axis=0), seg.gyro.std(axis=0)
    drift = float(np.max(smoothed_std(seg.timestamps, seg.accel)))
    if drift > REST_ACCEL_STD:
        log.warning("%s: the accelerometer's 0.1 s means vary by %.3f m/s^2 (std) over the rest interval: is it "
                    "at rest?", imu.source or "IMU", drift)
    norm = float(np.linalg.norm(a_mean))
    up = a_mean / norm
    if R_world_imu is not None:
        b_a = a_mean - np.asarray(R_world_imu, float).T @ np.array([0.0, 0.0, gravity])
    else:
        b_a = (norm - gravity) * up
    return StaticEstimate(w_mean, -up, b_a, a_mean, a_std, w_std, len(seg))
