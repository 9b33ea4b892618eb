"""The :class:`Dataset` base class every reader derives from, and the helpers they share.

Shared pieces (in :mod:`vslam.datasets.images`, :mod:`vslam.datasets.timestamps` and
:mod:`vslam.datasets.camera_yaml`, re-exported here):

* :func:`load_image` / :func:`load_depth`: decode one file with a :class:`DatasetError` that names
  it (missing, unreadable, truncated, wrong size) instead of OpenCV's silent ``None``.
* :func:`read_timestamped_list`: TUM-style ``timestamp filename`` lists (``rgb.txt``), checked sorted.
* :func:`interpolate_poses`: ground truth at arbitrary times (SLERP + linear translation).
* :func:`read_camera_yaml`: the small camera YAML (``fx fy cx cy width height [dist baseline
  depth_scale fps]``), also accepting ORB-SLAM style ``Camera.fx`` keys.

Iteration policy (see :meth:`Dataset.frames`): opening a dataset only lists files; images are
decoded lazily one frame at a time. A frame whose image cannot be decoded is skipped with a logging
warning and counted in :attr:`Dataset.skipped`, unless it is the first frame requested or more
than :attr:`Dataset.max_skip_fraction` of the requested range fails, which raises.
"""
from __future__ import annotations

import logging
from pathlib import Path
from typing import Iterator

import numpy as np

from vslam.datasets.camera_yaml import read_camera_yaml
from vslam.datasets.frame import Frame
from vslam.datasets.images import (
    IMAGE_EXTENSIONS,
    MAX_IMAGE_PIXELS,
    CorruptFrameError,
    image_header_size,
    list_images,
    load_depth,
    load_image,
    natural_key,
    require_dir,
    require_file,
)
from vslam.datasets.timestamps import check_timestamps, interpolate_poses, read_timestamped_list
from vslam.errors import DatasetError
from vslam.geometry.camera import PinholeCamera
from vslam.trajectory import Trajectory

__all__ = [
    "IMAGE_EXTENSIONS", "MAX_IMAGE_PIXELS", "SENSORS", "CorruptFrameError", "Dataset",
    "check_timestamps", "image_header_size", "interpolate_poses", "list_images", "load_depth", "load_image",
    "natural_key", "read_camera_yaml", "read_timestamped_list", "require_dir", "require_file",
]

log = logging.getLogger(__name__)

SENSORS = ("mono", "stereo", "rgbd")


# ----------------------------------------------------------------------------------------------
# Dataset
#: The depth noise of an RGB-D sensor registered to its colour camera, as the std of the virtual disparity
#: ``fx b / z`` in pixels. Structured-light and stereo depth errors grow as z^2: a Kinect's sigma_z =
#: 1.4e-3 z^2 m (Khoshelham & Elberink, Sensors 2012), a constant disparity std of fx b 1.4e-3 = 0.06 px
#: at the BA's virtual baseline; the registration and the 10-15 ms between the two images add to it. 0.1 px
#: is the middle of the range that improved both real TUM rows (0.06-0.15 px: fr1 desk 9 0.00406 ->
#: 0.0027-0.0030 m, fr3 cabinet 0.0294 -> 0.025-0.028 m; benchmarks/RESULTS.md, issue #24 round 6).
RGBD_DISPARITY_SIGMA_PX = 0.1


# ----------------------------------------------------------------------------------------------
class Dataset:
    """A sequence of :class:`Frame` records read lazily from disk.

    Subclasses set ``name``, ``kind``, ``camera``, ``sensors``, ``sensor``, ``frame_rate``,
    ``root`` and ``_timestamps`` in ``__init__`` and implement :meth:`_load` (decode frame ``i``)
    and :meth:`_gt_poses` (ground truth at every frame, NaN where unknown).
    """

    name: str = ""
    kind: str = ""
    camera: PinholeCamera
    sensors: tuple[str, ...] = ("mono",)
    sensor: str = "mono"
    frame_rate: float = 30.0
    root: Path
    #: the depth sensor's noise as a constant disparity std in pixels (:data:`RGBD_DISPARITY_SIGMA_PX`;
    #: None where the depth is not registered to the colour camera): the BA's ``rgbd_disparity_sigma_px``
    #: when that is -1 (auto)
    depth_disparity_sigma_px: float | None = RGBD_DISPARITY_SIGMA_PX
    #: iteration raises once more than this fraction of the requested frames failed to decode
    max_skip_fraction: float = 0.1
    #: IMU samples (:class:`vslam.inertial.ImuMeasurements`) and calibration, for readers that have
    #: them (EuRoC ``imu0/``); None otherwise
    imu = None
    imu_calibration = None

    def __init__(self) -> None:
        self._skipped: set[int] = set()
        self._timestamps = np.zeros(0)
        self._gt_cache: tuple[np.ndarray, np.ndarray] | None = None
        self._gt_error: Exception | None = None  # why the ground truth could not be read

    @property
    def skipped(self) -> int:
        """How many distinct frames were skipped so far because they failed to decode."""
        return len(self._skipped)

    # -- sensors --------------------------------------------------------------------------------
    def _select_sensor(self, sensor: str | None, default: str, missing: dict[str, str] | None = None) -> str:
        """Validate ``sensor`` against :attr:`sensors`; ``missing`` explains why one is absent."""
        if sensor is None:
            return default
        sensor = sensor.lower()
        if sensor not in SENSORS:
            raise DatasetError(f"unknown sensor {sensor!r}; use one of {', '.join(SENSORS)}")
        if sensor not in self.sensors:
            why = (missing or {}).get(sensor, "")
            raise DatasetError(
                f"{self.root}: sensor '{sensor}' is not available for this {self.kind} sequence"
                f"{': ' + why if why else ''} (available: {', '.join(self.sensors)})"
            )
        return sensor

    # -- sequence protocol ---------------------------------------------------------------------
    @property
    def timestamps(self) -> np.ndarray:
        """Frame timestamps in seconds ``(N,)``."""
        return self._timestamps

    def __len__(self) -> int:
        return len(self._timestamps)

    def __getitem__(self, i: int) -> Frame:
        n = len(self)
        if not isinstance(i, (int, np.integer)):
            raise TypeError("dataset indices must be integers; use frames(start, stop) for ranges")
        if i < 0:
            i += n
        if not 0 <= i < n:
            raise IndexError(f"frame {i} out of range (the sequence has {n} frames)")
        return self._load(int(i))

    def __iter__(self) -> Iterator[Frame]:
        return self.frames()

    def frames(self, start: int = 0, stop: int | None = None) -> Iterator[Frame]:
        """Yield frames ``start .. stop-1``, decoding one at a time (memory stays flat).

        Frames that fail to decode are skipped with a warning and counted in :attr:`skipped`;
        the first requested frame failing, or more than :attr:`max_skip_fraction` of the range,
        raises :class:`DatasetError`.
        """
        n = len(self)
        stop = n if stop is None else min(stop, n)
        start = max(0, start)
        total = max(stop - start, 0)
        failed = 0
        for i in range(start, stop):
            try:
                frame = self._load(i)
            except CorruptFrameError as exc:
                if i == start:
                    raise DatasetError(f"{exc} (the first frame must be readable)") from None
                failed += 1
                self._skipped.add(i)
                if failed > max(1, self.max_skip_fraction * total):
                    raise DatasetError(
                        f"{exc}; {failed} of {total} frames failed to decode, more than "
                        f"{self.max_skip_fraction:.0%}: the sequence is damaged, re-extract it"
                    ) from None
                log.warning("skipping frame %d: %s", i, exc)
                continue
            yield frame

    def _check_size(self, image: np.ndarray, path: Path) -> None:
        """Raise when an image does not have the calibrated size."""
        h, w = image.shape[:2]
        if (w, h) != (self.camera.width, self.camera.height):
            raise CorruptFrameError(
                f"{path}: image is {w}x{h} but the calibration says {self.camera.width}x{self.camera.height}; "
                f"fix the calibration or the image"
            )

    def _load(self, i: int) -> Frame:  # pragma: no cover - abstract
        raise NotImplementedError

    # -- ground truth --------------------------------------------------------------------------
    def _gt_poses(self) -> tuple[np.ndarray, np.ndarray] | None:
        """``(T_world_cam (N, 4, 4), valid (N,))`` at the frame timestamps, or None."""
        return None

    def _gt(self) -> tuple[np.ndarray, np.ndarray] | None:
        if self._gt_error is not None:
            raise self._gt_error
        if self._gt_cache is None:
            try:
                res = self._gt_poses()
            except Exception as exc:  # read once: the same error for every later call
                self._gt_error = exc
                raise
            if res is None:
                return None
            self._gt_cache = res
        return self._gt_cache

    def ground_truth_file(self) -> Path | None:
        """The file the ground truth is read from (``_gt_file`` of a reader that sets it), or None
        when there is none; :func:`vslam.datasets.ground_truth.resolve_ground_truth` names it."""
        path = getattr(self, "_gt_file", None)
        return Path(path) if path is not None and Path(path).is_file() else None

    def gt_pose(self, i: int) -> np.ndarray | None:
        """Ground-truth ``T_world_cam`` of frame ``i`` or None (also when the ground truth cannot be
        read: a frame is never lost over it; :meth:`ground_truth` raises, for the run to warn)."""
        try:
            gt = self._gt()
        except Exception:  # noqa: BLE001 - see resolve_ground_truth
            return None
        if gt is None or not gt[1][i]:
            return None
        return gt[0][i].copy()

    def ground_truth(self) -> Trajectory | None:
        """Ground truth at the frame timestamps (frames GT covers only), or None without GT.

        Poses are of the camera whose images the frames carry (for rectified stereo: the
        rectified left camera).
        """
        gt = self._gt()
        if gt is None or not np.any(gt[1]):
            return None
        T, valid = gt
        return Trajectory(self._timestamps[valid], T[valid])

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}(name={self.name!r}, frames={len(self)}, sensor={self.sensor!r}, "
            f"sensors={self.sensors}, frame_rate={self.frame_rate:g})"
        )
