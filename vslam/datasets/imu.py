"""IMU input: EuRoC-CSV sample files and the calibration files other tools write.

Samples (:func:`load_imu_csv`): EuRoC / TUM-VI ``imu0/data.csv`` and any ``--imu FILE`` in that
layout: ``timestamp, w_x, w_y, w_z, a_x, a_y, a_z`` per line (gyro rad/s, accelerometer m/s^2,
IMU frame); the timestamp in integer nanoseconds (EuRoC) or decimal seconds (with a ``.``); ``#``
comments and one header line are skipped. The samples are checked
(:func:`vslam.inertial.check_samples`): unsorted or duplicate stamps and a gyro in degrees are
errors, gaps over 50 ms a warning.

Calibration (:func:`read_imu_calibration`, one or more files merged, format detected per file):

* ``euroc-imu``: EuRoC ``imu0/sensor.yaml`` (``T_BS`` IMU -> body, ``rate_hz``,
  ``gyroscope_noise_density``, ``gyroscope_random_walk``, ``accelerometer_noise_density``,
  ``accelerometer_random_walk``); the camera's ``T_BS`` (cam0 ``sensor.yaml``, format
  ``euroc-camera``, or the ``T_body_cam`` argument) gives ``T_imu_cam = T_BS_imu^-1 T_BS_cam``.
* ``kalibr-imu``: Kalibr ``imu.yaml`` (the same four noise keys and ``update_rate``, at the top
  level or under ``imu0``).
* ``kalibr-camchain``: Kalibr ``camchain-imucam.yaml`` (``cam0: T_cam_imu``, ``timeshift_cam_imu``
  with ``t_imu = t_cam + timeshift``).
* ``orbslam3``: ORB-SLAM3 settings (``IMU.T_b_c1`` or ``Tbc`` camera -> IMU, ``IMU.NoiseGyro``,
  ``IMU.NoiseAcc``, ``IMU.GyroWalk``, ``IMU.AccWalk``, ``IMU.Frequency``).

A missing noise value or rate takes the documented default (:data:`vslam.inertial.DEFAULT_NOISE`,
EuRoC's ADIS16448) with a logged warning; missing extrinsics are an error.
"""
from __future__ import annotations

import logging
from pathlib import Path
from typing import Iterable

import numpy as np

from vslam.datasets.camera_yaml import load_yaml
from vslam.errors import CalibrationError, DatasetError
from vslam.inertial import ImuCalibration, ImuMeasurements, check_rigid, check_samples, with_defaults
from vslam.textfile import open_text

log = logging.getLogger(__name__)

IMU_FORMATS = {
    "euroc-imu": "EuRoC imu0/sensor.yaml", "euroc-camera": "EuRoC camera sensor.yaml",
    "kalibr-imu": "Kalibr imu.yaml", "kalibr-camchain": "Kalibr camchain-imucam.yaml",
    "orbslam3": "ORB-SLAM3 settings",
}
_NOISE_KEYS = {  # our name: (EuRoC / Kalibr key, ORB-SLAM3 key)
    "gyro_noise_density": ("gyroscope_noise_density", "IMU.NoiseGyro"),
    "gyro_random_walk": ("gyroscope_random_walk", "IMU.GyroWalk"),
    "accel_noise_density": ("accelerometer_noise_density", "IMU.NoiseAcc"),
    "accel_random_walk": ("accelerometer_random_walk", "IMU.AccWalk"),
}


# -- samples ----------------------------------------------------------------------------------
def _is_number(s: str) -> bool:
    try:
        float(s)
        return True
    except ValueError:
        return False


def load_imu_csv(path: str | Path) -> ImuMeasurements:
    """Read a EuRoC-layout IMU CSV (module docstring) into checked :class:`ImuMeasurements`.

    Raises :class:`DatasetError` naming the file (and line) for a missing or empty file, a
    malformed line, unsorted or duplicate stamps, or a gyro in degrees/s.
    """
    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"{path}: IMU file not found; give a EuRoC-layout CSV "
                           f"(timestamp [ns], w_x, w_y, w_z [rad/s], a_x, a_y, a_z [m/s^2])")
    t, rows = [], []
    first_data = True
    with open_text(path, DatasetError) as fh:
        for lineno, line in enumerate(fh, 1):
            line = line.strip()
            if not line or line.startswith("#"):
                continue
            parts = [p.strip() for p in line.replace(";", ",").split(",")]
            if first_data and not _is_number(parts[0]):
                first_data = False  # a header line without '#'
                continue
            first_data = False
            if len(parts) < 7:
                raise DatasetError(f"{path}:{lineno}: expected 7 columns 'timestamp, w_x, w_y, w_z, a_x, a_y, a_z', "
                                   f"got {len(parts)}: {line[:80]!r}")
            stamp = parts[0]
            try:
                t.append(float(stamp) if ("." in stamp or "e" in stamp.lower()) else int(stamp) * 1e-9)
                rows.append([float(v) for v in parts[1:7]])
            except ValueError:
                raise DatasetError(f"{path}:{lineno}: not a number in {line[:80]!r}; the columns are "
                                   f"timestamp [ns], w_x, w_y, w_z [rad/s], a_x, a_y, a_z [m/s^2]") from None
    if not rows:
        raise DatasetError(f"{path}: no IMU samples; the file must list 'timestamp [ns], w_x, w_y, w_z, a_x, a_y, "
                           f"a_z' rows")
    data = np.asarray(rows, dtype=np.float64)
    imu = ImuMeasurements(np.asarray(t, dtype=np.float64), data[:, :3], data[:, 3:6], source=str(path))
    check_samples(imu, str(path))
    return imu


# -- calibration ------------------------------------------------------------------------------
def detect_imu_format(data: dict) -> str | None:
    """The format of a parsed IMU calibration mapping (module docstring), or None."""
    keys = {str(k) for k in data}
    if any(k.startswith("IMU.") for k in keys) or "Tbc" in keys:
        return "orbslam3"
    if isinstance(data.get("cam0"), dict) and "T_cam_imu" in data["cam0"]:
        return "kalibr-camchain"
    if "T_BS" in keys and "intrinsics" in keys:
        return "euroc-camera"
    if "T_BS" in keys:
        return "euroc-imu"
    if "accelerometer_noise_density" in keys or "gyroscope_noise_density" in keys or (
            isinstance(data.get("imu0"), dict) and "gyroscope_noise_density" in data["imu0"]):
        return "kalibr-imu"
    return None


def _number(node: dict, key: str, path: Path, fmt: str) -> float | None:
    v = node.get(key)
    if v is None:
        return None
    try:
        x = float(v)
    except (TypeError, ValueError):
        raise CalibrationError(f"{path}: {IMU_FORMATS[fmt]}: '{key}' = {v!r} is not a number") from None
    if not np.isfinite(x) or x <= 0:
        raise CalibrationError(f"{path}: {IMU_FORMATS[fmt]}: '{key}' = {v!r} must be a positive number")
    return x


def _matrix(node, key: str, path: Path, fmt: str) -> np.ndarray:
    if isinstance(node, dict):
        if "data" not in node:
            raise CalibrationError(f"{path}: {IMU_FORMATS[fmt]}: '{key}' has no 'data' list")
        node = node["data"]
    try:
        return np.asarray(node, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise CalibrationError(f"{path}: {IMU_FORMATS[fmt]}: '{key}' is not a list of numbers") from None


def _read_one(path: Path) -> dict:
    """Partial calibration values found in one file (our field names)."""
    if not path.is_file():
        raise CalibrationError(f"{path}: IMU calibration file not found")
    data = load_yaml(path)
    fmt = detect_imu_format(data)
    if fmt is None:
        raise CalibrationError(
            f"{path}: unrecognised IMU calibration (keys: {', '.join(sorted(map(str, data))[:8])}); expected EuRoC "
            f"imu0/sensor.yaml (T_BS, gyroscope_noise_density ...), Kalibr imu.yaml or camchain-imucam.yaml "
            f"(cam0: T_cam_imu), or ORB-SLAM3 settings (IMU.T_b_c1, IMU.NoiseGyro ...)"
        )
    out: dict = {"format": fmt}
    where = f"{path} ({IMU_FORMATS[fmt]})"
    if fmt == "orbslam3":
        key = "IMU.T_b_c1" if "IMU.T_b_c1" in data else ("Tbc" if "Tbc" in data else None)
        if key is not None:
            out["T_imu_cam"] = check_rigid(_matrix(data[key], key, path, fmt), where, key)
        for name, (_k, orb_key) in _NOISE_KEYS.items():
            out[name] = _number(data, orb_key, path, fmt)
        out["rate_hz"] = _number(data, "IMU.Frequency", path, fmt)
    elif fmt == "kalibr-camchain":
        cam0 = data["cam0"]
        T_cam_imu = check_rigid(_matrix(cam0["T_cam_imu"], "cam0/T_cam_imu", path, fmt), where, "cam0/T_cam_imu")
        out["T_imu_cam"] = np.linalg.inv(T_cam_imu)
        shift = cam0.get("timeshift_cam_imu")
        if shift is not None:
            try:
                out["time_offset"] = float(shift)
            except (TypeError, ValueError):
                raise CalibrationError(f"{where}: 'cam0/timeshift_cam_imu' = {shift!r} is not a number") from None
    else:
        node = data["imu0"] if fmt == "kalibr-imu" and isinstance(data.get("imu0"), dict) else data
        if fmt == "euroc-camera":
            out["T_body_cam"] = check_rigid(_matrix(node["T_BS"], "T_BS", path, fmt), where, "T_BS")
            return out
        if fmt == "euroc-imu":
            out["T_body_imu"] = check_rigid(_matrix(node["T_BS"], "T_BS", path, fmt), where, "T_BS")
        for name, (key, _o) in _NOISE_KEYS.items():
            out[name] = _number(node, key, path, fmt)
        out["rate_hz"] = _number(node, "rate_hz" if fmt == "euroc-imu" else "update_rate", path, fmt)
    return out


def read_imu_calibration(paths: str | Path | Iterable[str | Path], T_body_cam: np.ndarray | None = None,
                         gravity: float | None = None) -> ImuCalibration:
    """Merge the IMU calibration found in ``paths`` (formats in the module docstring; the first
    file giving a value wins) into an :class:`ImuCalibration`.

    ``T_body_cam`` (``(4, 4)``, camera -> body, e.g. EuRoC cam0's ``T_BS``) is used when no file
    gives ``T_imu_cam`` directly. Missing noise values / rate take the documented defaults with a
    warning; missing extrinsics raise :class:`CalibrationError`.
    """
    paths = [Path(paths)] if isinstance(paths, (str, Path)) else [Path(p) for p in paths]
    merged: dict = {}
    for p in paths:
        for k, v in _read_one(p).items():
            if v is not None and merged.get(k) is None:
                merged[k] = v
    where = ", ".join(map(str, paths)) or "IMU calibration"
    if merged.get("T_imu_cam") is None:
        T_bc = merged.get("T_body_cam", T_body_cam)
        if T_bc is None:
            raise CalibrationError(
                f"{where}: no camera-IMU extrinsics; add a Kalibr camchain-imucam.yaml (cam0: T_cam_imu), ORB-SLAM3 "
                f"settings (IMU.T_b_c1) or the camera's EuRoC sensor.yaml (T_BS)"
            )
        T_bc = check_rigid(T_bc, where, "T_body_cam")
        T_bi = merged.get("T_body_imu", np.eye(4))
        merged["T_imu_cam"] = np.linalg.inv(T_bi) @ T_bc
    values = with_defaults({k: merged.get(k) for k in ("gyro_noise_density", "gyro_random_walk", "accel_noise_density",
                                                       "accel_random_walk", "rate_hz")}, where)
    kwargs = {"time_offset": float(merged.get("time_offset", 0.0))}
    if gravity is not None:
        kwargs["gravity"] = float(gravity)
    return ImuCalibration(T_imu_cam=merged["T_imu_cam"], source=where, **values, **kwargs)


def euroc_imu_calibration(imu_yaml: Path, T_body_cam: np.ndarray) -> ImuCalibration:
    """EuRoC: ``imu0/sensor.yaml`` with the camera's ``T_BS``; without the file the IMU is taken as
    the body frame (as in EuRoC) and the noise values default, with a warning."""
    if imu_yaml.is_file():
        return read_imu_calibration([imu_yaml], T_body_cam=T_body_cam)
    log.warning("%s: not found; taking the IMU as the body frame (T_imu_cam = cam0 T_BS)", imu_yaml)
    values = with_defaults({}, str(imu_yaml))
    return ImuCalibration(T_imu_cam=check_rigid(T_body_cam, str(imu_yaml), "T_BS"), source=str(imu_yaml), **values)


# -- the IMU of a run ---------------------------------------------------------------------------
#: Calibration files looked for beside an ``--imu FILE`` (first found first; merged).
IMU_CALIBRATION_NAMES = ("camchain-imucam.yaml", "imu.yaml", "sensor.yaml")


def dataset_imu(dataset, imu_file: str | Path | None = None) -> tuple[ImuMeasurements, ImuCalibration]:
    """``(samples, calibration)`` for an inertial run on ``dataset``: ``imu_file`` (EuRoC CSV
    columns, :func:`load_imu_csv`) when given, else the dataset's own (EuRoC ``imu0/``). The
    calibration is the dataset's (``imu_calibration``), else read from the files beside
    ``imu_file`` (:data:`IMU_CALIBRATION_NAMES`, :func:`read_imu_calibration`); it refers to the
    frames' camera (``T_cam0_rect``: the rectified left camera of a stereo rig). A dataset without
    IMU, or an IMU without calibration, is one :class:`DatasetError` / :class:`CalibrationError`
    naming what is missing; samples that do not overlap the images are refused
    (:func:`vslam.inertial.check_overlap`)."""
    from vslam.inertial import check_overlap

    where = str(getattr(dataset, "root", None) or getattr(dataset, "path", "") or "the sequence")
    if imu_file is None:
        imu = getattr(dataset, "imu", None)
        if imu is None:
            raise DatasetError(
                f"{where}: this {getattr(dataset, 'kind', '')} sequence has no IMU data (EuRoC / TUM-VI: "
                f"mav0/imu0/data.csv); an inertial sensor needs one: pass --imu FILE (EuRoC CSV columns) or run "
                f"--sensor {getattr(dataset, 'sensor', 'mono')}"
            )
    else:
        path = Path(imu_file)
        if not path.is_file():
            raise DatasetError(f"{path}: IMU file not found")
        imu = load_imu_csv(path)
    calib = getattr(dataset, "imu_calibration", None)
    if calib is None:
        if imu_file is None:
            raise CalibrationError(f"{where}: the IMU has no calibration (camera-IMU extrinsics)")
        found = [Path(imu_file).parent / n for n in IMU_CALIBRATION_NAMES if (Path(imu_file).parent / n).is_file()]
        if not found:
            raise CalibrationError(
                f"{imu_file}: no IMU calibration beside it ({', '.join(IMU_CALIBRATION_NAMES)}); the camera-IMU "
                f"extrinsics are needed: a Kalibr camchain-imucam.yaml (cam0: T_cam_imu) or ORB-SLAM3 settings "
                f"(IMU.T_b_c1) in the same folder"
            )
        calib = read_imu_calibration(found)
    T_cam_frame = getattr(dataset, "T_cam0_rect", None)
    if T_cam_frame is not None:
        calib = calib.with_camera(T_cam_frame)
    t = np.asarray(dataset.timestamps, float)
    if imu_file is not None and len(t):
        check_overlap(imu, float(t[0]), float(t[-1]), str(imu_file), calib.time_offset)
    return imu, calib
