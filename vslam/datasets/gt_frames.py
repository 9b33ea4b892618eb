"""Whose pose a ground-truth file gives: EuRoC's body-frame ground truth converted to cam0, and the
ground truth of a sequence written as a TUM file (``vslam gt``).

EuRoC's ``mav0/state_groundtruth_estimate0/data.csv`` (17 columns: position, quaternion, velocity,
gyroscope and accelerometer biases) holds ``T_world_body`` of the IMU body, not of a camera: a camera
trajectory compared with it as it is shows a ~90 degree rotation error and, aligned in SE(3), the
lever arm between the IMU and the camera as position error. :func:`body_frame_reference` detects
such a file and takes cam0's ``T_BS`` (``T_body_cam0``) from ``mav0/cam0/sensor.yaml`` beside it:
``T_world_cam0 = T_world_body @ T_BS``, the conversion the EuRoC reader makes for a run.

Example::

    conv = body_frame_reference("MH_01/mav0/state_groundtruth_estimate0/data.csv")
    conv.T_body_cam, conv.sensor_yaml        # (4, 4), ".../mav0/cam0/sensor.yaml"
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from vslam.errors import DatasetError, TrajectoryError
from vslam.textfile import open_text

#: the folder of EuRoC's body-frame ground truth
BODY_GT_FOLDER = "state_groundtruth_estimate0"
#: columns of a ``state_groundtruth_estimate0/data.csv`` row
BODY_GT_COLUMNS = 17


@dataclass(frozen=True)
class BodyToCamera:
    """A body-frame reference to convert: ``T_body_cam`` (``T_BS`` of ``sensor_yaml``)."""

    file: Path
    sensor_yaml: Path
    T_body_cam: np.ndarray

    def line(self) -> str:
        """The one line saying so."""
        return (f"reference {self.file}: EuRoC body-frame (IMU) poses, converted to cam0 with T_BS of "
                f"{self.sensor_yaml} (T_world_cam0 = T_world_body T_BS)")


def is_euroc_body_gt(path: str | Path) -> bool:
    """Whether ``path`` is EuRoC body-frame ground truth: a comma-separated file whose header names
    the state estimate's columns (``p_RS_R_x`` ... ``v_RS_R_x``) or whose first row has 17 values."""
    path = Path(path)
    header, first = "", ""
    try:
        with open_text(path, TrajectoryError) as fh:
            for line in fh:
                s = line.strip()
                if s.startswith("#") and not header:
                    header = s
                elif s and not s.startswith("#"):
                    first = s
                    break
    except (OSError, UnicodeDecodeError, TrajectoryError):
        return False
    if "," not in first:
        return False
    named = "p_RS_R" in header and "v_RS_R" in header
    return named or len(first.split(",")) == BODY_GT_COLUMNS


def cam0_sensor_beside(path: str | Path) -> Path | None:
    """``mav0/cam0/sensor.yaml`` of the ``mav0`` folder holding ``path`` (``mav0/<folder>/data.csv``),
    or None."""
    mav0 = Path(path).resolve().parent.parent
    cand = mav0 / "cam0" / "sensor.yaml"
    return cand if cand.is_file() else None


def body_frame_reference(path: str | Path, sensor_yaml: str | Path | None = None,
                         option: str | None = "--body-to-cam") -> BodyToCamera | None:
    """The conversion of a EuRoC body-frame reference ``path`` to the camera of ``sensor_yaml``
    (default: cam0's ``sensor.yaml`` beside its ``mav0`` folder); None when ``path`` is not one.

    Raises :class:`TrajectoryError` (one line, with the fix; ``option`` the command's option naming
    the ``sensor.yaml``, None: it has none) when it is one and no ``sensor.yaml`` is found, or the one
    given has no usable ``T_BS``.
    """
    path = Path(path)
    if not is_euroc_body_gt(path):
        return None
    yaml_path = Path(sensor_yaml) if sensor_yaml is not None else cam0_sensor_beside(path)
    if yaml_path is None:
        fix = (f"pass {option} MAV0/cam0/sensor.yaml, write the camera's ground truth with `vslam gt SEQUENCE -o "
               f"gt.txt`, or {option} none to compare the body poses as they are") if option else \
            "put the sequence's mav0/cam0/sensor.yaml beside it, or pass the camera's ground truth written by " \
            "`vslam gt SEQUENCE -o gt.txt`"
        raise TrajectoryError(f"{path}: EuRoC body-frame ground truth (poses of the IMU body, not of a camera) "
                              f"and no mav0/cam0/sensor.yaml beside it to convert it to the camera; {fix}")
    return BodyToCamera(path, yaml_path, _T_BS(yaml_path))


def _T_BS(yaml_path: Path) -> np.ndarray:
    """``T_BS`` (``T_body_sensor``) of a EuRoC ``sensor.yaml``, checked rigid."""
    from vslam.datasets.camera_yaml import load_yaml

    if not yaml_path.is_file():
        raise TrajectoryError(f"--body-to-cam {yaml_path}: no such file; name a EuRoC sensor.yaml (mav0/cam0/)")
    try:
        data = load_yaml(yaml_path)
        T = np.array(data["T_BS"]["data"], dtype=float).reshape(4, 4)
    except DatasetError as exc:
        raise TrajectoryError(str(exc)) from None
    except (KeyError, TypeError, ValueError):
        raise TrajectoryError(f"{yaml_path}: no T_BS (16 numbers under T_BS: data:); name a EuRoC sensor.yaml") from None
    R = T[:3, :3]
    if not (np.all(np.isfinite(T)) and np.allclose(T[3], [0, 0, 0, 1])
            and np.allclose(R @ R.T, np.eye(3), atol=1e-4) and np.linalg.det(R) > 0):
        raise TrajectoryError(f"{yaml_path}: T_BS is not a rigid transform (rotation not orthonormal)")
    return T


def ground_truth_of(ds: Any) -> tuple[Any, str, str]:
    """``(trajectory, file, frame)``: the ground truth a run over ``ds`` is evaluated against, at
    the frame timestamps, the file it comes from and whose pose it is. Raises :class:`DatasetError`
    when the sequence has none or it cannot be used (the problem named)."""
    from vslam.datasets.ground_truth import resolve_ground_truth

    truth = resolve_ground_truth(ds)
    if truth.trajectory is None:
        why = truth.problem or "no ground truth found"
        raise DatasetError(f"{truth.file or getattr(ds, 'root', 'the sequence')}: {why}")
    frame = truth.frame or "camera"
    if getattr(ds, "kind", "") == "euroc" and getattr(ds, "sensor", "") == "stereo":
        frame = "cam0 rectified (the left camera of a stereo run; same positions as cam0)"
    return truth.trajectory, truth.file or "", frame
