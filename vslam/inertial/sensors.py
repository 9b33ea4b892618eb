"""Sensor names: the visual sensors and their inertial variants.

An inertial sensor (``mono-inertial``, ``stereo-inertial``, ``rgbd-inertial``) runs its visual part
exactly as the base sensor (``mono``, ``stereo``, ``rgbd``: same dataset reader, same tracker and
map) and adds the IMU on top (initialization, prediction).

Example:
    >>> split_sensor("stereo-inertial")
    ('stereo', True)
    >>> split_sensor("mono")
    ('mono', False)
"""
from __future__ import annotations

from vslam.errors import ConfigError

VISUAL_SENSORS = ("mono", "stereo", "rgbd")
INERTIAL_SUFFIX = "-inertial"
INERTIAL_SENSORS = tuple(s + INERTIAL_SUFFIX for s in VISUAL_SENSORS)
ALL_SENSORS = VISUAL_SENSORS + INERTIAL_SENSORS


def split_sensor(sensor: str) -> tuple[str, bool]:
    """``(base visual sensor, inertial)`` of a sensor name; :class:`ConfigError` for an unknown one."""
    if sensor in VISUAL_SENSORS:
        return sensor, False
    if sensor in INERTIAL_SENSORS:
        return sensor[: -len(INERTIAL_SUFFIX)], True
    raise ConfigError(f"unknown sensor {sensor!r}; use one of {', '.join(ALL_SENSORS)}")


def is_inertial(sensor: str | None) -> bool:
    """Whether ``sensor`` names an inertial mode (None: no)."""
    return sensor is not None and sensor in INERTIAL_SENSORS
