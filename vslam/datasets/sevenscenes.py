"""Microsoft 7-Scenes sequences (Shotton et al., CVPR 2013).

``seq-XX/frame-XXXXXX.color.png|jpg``, ``frame-XXXXXX.depth.png`` (uint16 millimetres, 0 and
65535 invalid), ``frame-XXXXXX.pose.txt`` (4x4 ``T_world_cam``, KinectFusion). No timestamps:
``t = frame_number / 30``. Nominal intrinsics fx = fy = 585, cx = 320, cy = 240 for colour and
depth (they are not precisely registered in 7-Scenes). Accepts the scene folder holding exactly one
``seq-*`` folder, or the ``seq-*`` folder itself. Sensors: ``rgbd`` (default) and ``mono``.
"""
from __future__ import annotations

import logging
import os
import re
from pathlib import Path

import numpy as np

from vslam.datasets.base import Dataset, load_depth, load_image, require_dir
from vslam.datasets.frame import Frame
from vslam.errors import DatasetError
from vslam.geometry.camera import PinholeCamera

log = logging.getLogger(__name__)

SEVENSCENES_CAMERA = PinholeCamera(585.0, 585.0, 320.0, 240.0, 640, 480)
SEVENSCENES_FPS = 30.0
SEVENSCENES_DEPTH_SCALE = 1000.0
_COLOR_RE = re.compile(r"^frame-(\d+)\.color\.(png|jpg|jpeg)$", re.IGNORECASE)


def read_pose_file(path: Path) -> np.ndarray | None:
    """A 4x4 ``T_world_cam`` from a 7-Scenes ``pose.txt``; None if missing or not finite."""
    try:
        T = np.loadtxt(path, dtype=float)
    except FileNotFoundError:
        return None
    except ValueError:
        raise DatasetError(f"{path}: pose file must hold a 4x4 matrix of numbers") from None
    if T.shape != (4, 4):
        raise DatasetError(f"{path}: pose file must hold a 4x4 matrix, got shape {T.shape}")
    if not np.all(np.isfinite(T)):
        return None  # 7-Scenes marks lost tracking with inf
    return T


class SevenScenesDataset(Dataset):
    """One 7-Scenes sequence."""

    kind = "7scenes"
    # its depth is not registered to the colour camera: a depth weight for the z^2 law made the
    # redkitchen RGB-D row worse at every value tried (0.0433 -> 0.046-0.057 m; benchmarks/RESULTS.md,
    # issue #24 item 3), so the BA keeps the octave-scaled disparity weight
    depth_disparity_sigma_px = None

    def __init__(
        self, path: str | Path, sensor: str | None = None, camera: PinholeCamera | None = None
    ) -> None:
        super().__init__()
        path = require_dir(path, "7-Scenes folder")
        if not path.name.startswith("seq-"):
            seqs = sorted(p for p in path.glob("seq-*") if p.is_dir())
            if len(seqs) == 1:
                path = seqs[0]
            elif len(seqs) > 1:
                raise DatasetError(
                    f"{path}: holds {len(seqs)} sequences ({', '.join(p.name for p in seqs)}); pass one seq-* folder"
                )
        self.root = path
        self.name = f"{path.parent.name}/{path.name}" if path.name.startswith("seq-") else path.name
        ids, colors = [], []
        for entry in os.scandir(path):
            m = _COLOR_RE.match(entry.name)
            if m:
                ids.append(int(m.group(1)))
                colors.append(entry.name)
        if not ids:
            raise DatasetError(f"{path}: no frame-XXXXXX.color.png/jpg files; is this a 7-Scenes seq-* folder?")
        order = np.argsort(ids)
        self._ids = np.array(ids, dtype=int)[order]
        if np.any(np.diff(self._ids) == 0):
            raise DatasetError(f"{path}: frame {self._ids[np.argmax(np.diff(self._ids) == 0)]} has two colour images")
        self._colors = [colors[k] for k in order]
        has_depth = (path / f"frame-{self._ids[0]:06d}.depth.png").is_file()
        self.sensors = ("mono", "rgbd") if has_depth else ("mono",)
        self.sensor = self._select_sensor(sensor, "rgbd" if has_depth else "mono", {
            "rgbd": f"no {path / f'frame-{self._ids[0]:06d}.depth.png'}", "stereo": "7-Scenes is not stereo",
        })
        self.camera = camera if camera is not None else SEVENSCENES_CAMERA
        self.frame_rate = SEVENSCENES_FPS
        self.depth_scale = SEVENSCENES_DEPTH_SCALE
        self._timestamps = self._ids / SEVENSCENES_FPS

    def _pose_path(self, i: int) -> Path:
        return self.root / f"frame-{self._ids[i]:06d}.pose.txt"

    def _gt_poses(self):
        if not self._pose_path(0).is_file():
            return None
        n = len(self)
        T = np.full((n, 4, 4), np.nan)
        valid = np.zeros(n, dtype=bool)
        for i in range(n):
            Ti = read_pose_file(self._pose_path(i))
            if Ti is not None:
                T[i], valid[i] = Ti, True
        return T, valid

    def gt_pose(self, i: int) -> np.ndarray | None:
        if self._gt_cache is not None or self._gt_error is not None:
            return super().gt_pose(i)
        try:
            return read_pose_file(self._pose_path(i))  # one small file; avoids reading all poses
        except DatasetError:
            return None  # a bad pose file never stops the frames (the run warns about the ground truth)

    def _load(self, i: int) -> Frame:
        path = self.root / self._colors[i]
        image = load_image(path)
        self._check_size(image, path)
        depth = None
        if self.sensor == "rgbd":
            dpath = self.root / f"frame-{self._ids[i]:06d}.depth.png"
            depth = load_depth(dpath, self.depth_scale, image.shape[:2], invalid=(0, 65535))
        return Frame(
            index=int(self._ids[i]), timestamp=float(self._timestamps[i]), image=image, camera=self.camera,
            depth=depth, T_world_cam=self.gt_pose(i), path=str(path),
        )
