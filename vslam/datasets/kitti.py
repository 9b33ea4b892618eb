"""KITTI odometry sequences (Geiger et al., CVPR 2012), devkit layout.

``sequences/NN/{calib.txt, times.txt, image_0/, image_1/}`` and ``poses/NN.txt`` two levels up.

* ``calib.txt``: lines ``P0: 12 numbers`` (3x4 row-major projection matrices of the rectified
  cameras; unlabelled lines are read as P0, P1, ... in order). Only P0 (and P1 for stereo) are
  needed: ``K = P0[:, :3]`` and ``baseline = (P0[0,3] - P1[0,3]) / P1[0,0]`` (= -P1[0,3]/fx).
* ``times.txt``: one timestamp (s) per frame, line k for image ``k``.
* Images: 8-bit grayscale rectified PNGs ``000000.png`` ...; frame numbers come from the names, so
  a clip holding frames 0-159 of a longer sequence reads times and poses of those rows only.
* Ground truth: ``poses/NN.txt``, KITTI format, ``T_world_cam0``.

Sensors: ``stereo`` when ``image_1/`` exists (the default then), always ``mono``.
"""
from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from vslam.datasets.base import (
    Dataset,
    check_timestamps,
    list_images,
    load_image,
    require_dir,
    require_file,
)
from vslam.datasets.calib_checks import check_camera, check_file_size
from vslam.datasets.frame import Frame
from vslam.errors import CalibrationError, DatasetError, TrajectoryError
from vslam.textfile import open_text
from vslam.trajectory import read_kitti
from vslam.geometry.camera import PinholeCamera

log = logging.getLogger(__name__)


def read_kitti_calib(path: str | Path) -> dict[str, np.ndarray]:
    """Parse a KITTI ``calib.txt`` into ``{"P0": (3, 4), "P1": (3, 4), ...}``."""
    path = Path(path)
    if not path.is_file():
        raise CalibrationError(f"{path}: KITTI calib.txt not found; it must hold at least 'P0:' (and 'P1:' for stereo)")
    check_file_size(path)
    out: dict[str, np.ndarray] = {}
    k = 0
    with open_text(path, CalibrationError) as fh:
        for lineno, line in enumerate(fh, 1):
            line = line.strip()
            if not line or line.startswith("#"):
                continue
            if ":" in line:
                key, _, rest = line.partition(":")
                key = key.strip()
            else:
                key, rest = f"P{k}", line
            k += 1
            try:
                vals = np.array([float(v) for v in rest.split()])
            except ValueError:
                raise CalibrationError(f"{path}:{lineno}: '{key}' has a value that is not a number") from None
            if key.startswith("P") and key[1:].isdigit():
                if vals.size != 12 or not np.all(np.isfinite(vals)):
                    raise CalibrationError(
                        f"{path}:{lineno}: '{key}' needs 12 finite numbers (3x4 projection matrix), got {vals.size}"
                    )
                out[key] = vals.reshape(3, 4)
    if "P0" not in out:
        raise CalibrationError(f"{path}: no 'P0:' projection matrix; add the left camera's 3x4 P0 line")
    return out


class KittiDataset(Dataset):
    """One KITTI odometry sequence folder ``sequences/NN``."""

    kind = "kitti"

    def __init__(self, path: str | Path, sensor: str | None = None) -> None:
        super().__init__()
        self.root = root = require_dir(path, "KITTI sequence folder")
        self.name = f"kitti_{root.name}"
        left_dir = root / "image_0"
        if not left_dir.is_dir():
            raise DatasetError(f"{left_dir}: not found; a KITTI sequence needs image_0/ with the left images")
        self._left = list_images(left_dir)
        if not self._left:
            raise DatasetError(f"{left_dir}: holds no images")
        try:
            self._ids = np.array([int(p.stem) for p in self._left])
        except ValueError:
            raise DatasetError(f"{left_dir}: image names must be frame numbers like 000000.png") from None

        calib = read_kitti_calib(root / "calib.txt")
        P0 = calib["P0"]
        if P0[0, 0] <= 0 or P0[1, 1] <= 0:
            raise CalibrationError(f"{root / 'calib.txt'}: P0 has non-positive focal length {P0[0, 0]}")
        baseline = None
        if "P1" in calib:
            P1 = calib["P1"]
            baseline = float((P0[0, 3] - P1[0, 3]) / P1[0, 0])
            if baseline <= 0:
                raise CalibrationError(
                    f"{root / 'calib.txt'}: P1 gives baseline {baseline:.4f} m; P1[0,3] must be -fx*baseline"
                )

        right_dir = root / "image_1"
        has_right = right_dir.is_dir() and any(right_dir.iterdir())
        self.sensors = ("mono", "stereo") if has_right and baseline else ("mono",)
        why = "no image_1/ folder" if not has_right else "calib.txt has no 'P1:' line"
        self.sensor = self._select_sensor(sensor, "stereo" if "stereo" in self.sensors else "mono", {
            "stereo": why, "rgbd": "KITTI has no depth images",
        })

        times_path = require_file(root / "times.txt", "KITTI times.txt")
        try:
            times = np.loadtxt(times_path, ndmin=1, dtype=float)
        except ValueError:
            raise DatasetError(f"{times_path}: every line must be one timestamp in seconds") from None
        if times.ndim != 1:
            raise DatasetError(f"{times_path}: every line must be one timestamp in seconds")
        if self._ids.max() >= len(times):
            raise DatasetError(
                f"{times_path}: has {len(times)} timestamps but image_0/ holds frame {self._ids.max()}; "
                f"times.txt must have a line per frame"
            )
        self._timestamps = times[self._ids]
        check_timestamps(self._timestamps, times_path)

        first = load_image(self._left[0], grayscale=False)
        self.camera = check_camera(PinholeCamera(
            float(P0[0, 0]), float(P0[1, 1]), float(P0[0, 2]), float(P0[1, 2]),
            first.shape[1], first.shape[0], baseline=baseline,
        ), f"{root / 'calib.txt'}: P0")
        self.frame_rate = 10.0
        self._right_dir = right_dir if self.sensor == "stereo" else None
        seq = root.name
        self._gt_file = root.parent.parent / "poses" / f"{seq}.txt"

    def _gt_poses(self):
        if not self._gt_file.is_file():
            return None
        try:
            gt = read_kitti(self._gt_file)
        except TrajectoryError as exc:
            raise DatasetError(str(exc)) from None
        n = len(self)
        T = np.full((n, 4, 4), np.nan)
        valid = self._ids < len(gt)
        T[valid] = gt.T_world_cam[self._ids[valid]]
        if not np.all(valid):
            log.warning("%s: %d of %d frames have no pose row", self._gt_file, int((~valid).sum()), n)
        return T, valid

    def _load(self, i: int) -> Frame:
        path = self._left[i]
        image = load_image(path)
        self._check_size(image, path)
        right = None
        if self._right_dir is not None:
            right = load_image(self._right_dir / path.name)
            self._check_size(right, self._right_dir / path.name)
        return Frame(
            index=int(self._ids[i]), timestamp=float(self._timestamps[i]), image=image, camera=self.camera,
            image_right=right, T_world_cam=self.gt_pose(i), path=str(path),
        )
