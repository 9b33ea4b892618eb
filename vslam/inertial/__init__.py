"""Inertial measurements: IMU samples, calibration, preintegration (on GTSAM), static initialization.

A low layer directly above :mod:`vslam.geometry` (its rotations are :mod:`vslam.geometry.lie`'s; no stage
imports; readers live in :mod:`vslam.datasets`)::

    imu = dataset.imu                                  # ImuMeasurements (EuRoC imu0/)
    calib = dataset.imu_calibration                    # ImuCalibration (T_imu_cam, noise, rate)
    d = preintegrated_delta(imu, t_i, t_j, calib, ImuBias(b_g, b_a))   # dR, dv, dp, dt
"""
from vslam.inertial.calibration import (
    DEFAULT_NOISE, DEFAULT_RATE_HZ, STANDARD_GRAVITY, ImuCalibration, check_rigid, with_defaults,
)
from vslam.inertial.checks import MAX_GAP_S, check_overlap, check_samples, gyro_in_degrees
from vslam.inertial.measurements import ImuMeasurements
from vslam.inertial.preintegration import (
    ImuBias, ImuDelta, delta_of, gravity_vector, make_params, predict, preintegrate, preintegrated_delta,
)
from vslam.inertial.static import StaticEstimate, estimate_static, rotation_to_up

__all__ = [
    "DEFAULT_NOISE", "DEFAULT_RATE_HZ", "MAX_GAP_S", "STANDARD_GRAVITY", "ImuBias", "ImuCalibration", "ImuDelta",
    "ImuMeasurements", "StaticEstimate", "check_overlap", "check_rigid", "check_samples", "delta_of",
    "estimate_static", "gravity_vector", "gyro_in_degrees", "make_params", "predict", "preintegrate",
    "preintegrated_delta", "rotation_to_up", "with_defaults",
]
