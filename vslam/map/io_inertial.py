"""The inertial state of a saved map (documented in ``FORMAT.md``, "Visual-inertial maps").

A visual-inertial map keeps, besides ``map_attributes.gravity_aligned``:

* per keyframe, in its ``extra`` dict: ``imu_velocity`` ``(3,) float64`` (world frame, m/s) and
  ``imu_bias`` ``(6,) float64`` (gyroscope rad/s then accelerometer m/s^2), stored as the dict
  field's ``.npz`` members (bit-exact);
* in ``metadata["inertial"]``: ``gravity_m_s2`` (the magnitude used), ``imu_calibration_source`` (the
  file(s) the IMU calibration was read from) and ``T_imu_cam`` (4x4, camera -> IMU).

:func:`check_inertial_extras` (on load) and :func:`check_inertial_metadata` (on save and load) refuse
what the format cannot mean: wrong shape or dtype, NaN/inf, a gravity that is not ~9.8 m/s^2.
:func:`inertial_metadata` builds the metadata entry from an :class:`vslam.inertial.ImuCalibration`;
:func:`map_bias` gives the biases a new session starts with in the map (its keyframes' median).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Iterable

import numpy as np

from vslam.errors import MapFormatError
from vslam.inertial import ImuBias
from vslam.map.keyframe import KeyFrame

#: shape of each inertial entry of ``KeyFrame.extra`` (all float64)
IMU_EXTRA_SHAPES: dict[str, tuple[int, ...]] = {"imu_velocity": (3,), "imu_bias": (6,)}
#: ``metadata["inertial"]`` keys
INERTIAL_METADATA_KEYS = ("gravity_m_s2", "imu_calibration_source", "T_imu_cam")
#: a gravity magnitude outside this range (m/s^2; Earth's is 9.76-9.83) is corrupted or in other units
#: (g, ft/s^2); the range is wide enough for a deliberately set calibration value
GRAVITY_RANGE = (9.0, 10.5)


def inertial_metadata(calibration: Any) -> dict:
    """``metadata["inertial"]`` of a map built with the IMU calibration ``calibration``
    (:class:`vslam.inertial.ImuCalibration`: ``gravity``, ``source``, ``T_imu_cam``)."""
    return {
        "gravity_m_s2": float(calibration.gravity),
        "imu_calibration_source": str(calibration.source or ""),
        "T_imu_cam": [[float(x) for x in row] for row in np.asarray(calibration.T_imu_cam, float)],
    }


def check_inertial_metadata(where: str | Path, metadata: dict) -> None:
    """Refuse a malformed ``metadata["inertial"]`` (absent is fine: a visual map)."""
    entry = metadata.get("inertial")
    if entry is None:
        return
    if not isinstance(entry, dict) or set(entry) != set(INERTIAL_METADATA_KEYS):
        raise MapFormatError(f"{where}: metadata.inertial must hold exactly {list(INERTIAL_METADATA_KEYS)}, "
                             f"got {sorted(entry) if isinstance(entry, dict) else type(entry).__name__}")
    g = entry["gravity_m_s2"]
    if isinstance(g, bool) or not isinstance(g, (int, float)) or not GRAVITY_RANGE[0] <= g <= GRAVITY_RANGE[1]:
        raise MapFormatError(f"{where}: metadata.inertial.gravity_m_s2 = {g!r} is not a gravity magnitude "
                             f"({GRAVITY_RANGE[0]}-{GRAVITY_RANGE[1]} m/s^2)")
    if not isinstance(entry["imu_calibration_source"], str):
        raise MapFormatError(f"{where}: metadata.inertial.imu_calibration_source must be a string")
    T = np.asarray(entry["T_imu_cam"], dtype=float) if isinstance(entry["T_imu_cam"], list) else None
    if T is None or T.shape != (4, 4) or not np.all(np.isfinite(T)) or not np.allclose(T[3], [0, 0, 0, 1]) \
            or not np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-6):
        raise MapFormatError(f"{where}: metadata.inertial.T_imu_cam must be a finite rigid 4x4 transform")


def check_inertial_extras(where: str | Path, keyframes: Iterable[KeyFrame]) -> int:
    """Check every keyframe's ``imu_velocity`` / ``imu_bias`` (when present): a float64 array of the
    documented shape, finite. Returns the number of keyframes carrying a velocity."""
    n = 0
    for kf in keyframes:
        for key, shape in IMU_EXTRA_SHAPES.items():
            if key not in kf.extra:
                continue
            v = kf.extra[key]
            if not isinstance(v, np.ndarray) or v.dtype != np.float64 or v.shape != shape or not np.all(np.isfinite(v)):
                got = f"{v.dtype}{list(v.shape)}" if isinstance(v, np.ndarray) else type(v).__name__
                raise MapFormatError(f"{where}: keyframe {kf.id} extra[{key!r}] must be finite float64{list(shape)}, "
                                     f"got {got}; the map is corrupted")
        n += "imu_velocity" in kf.extra
    return n


def map_bias(keyframes: Iterable[KeyFrame]) -> ImuBias:
    """The median of the keyframes' stored biases (``extra["imu_bias"]``, gyro then accelerometer);
    zero biases when none stores one."""
    stored = [np.asarray(kf.extra["imu_bias"], float) for kf in keyframes
              if getattr(kf, "extra", None) and "imu_bias" in kf.extra]
    b = np.median(np.stack(stored), axis=0) if stored else np.zeros(6)
    return ImuBias(b[:3], b[3:])
