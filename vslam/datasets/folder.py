"""A folder of images or a video file, calibrated by the small camera YAML. Mono only.

The camera comes from the ``camera`` argument (a :class:`PinholeCamera` or a YAML path), else
``camera.yaml`` beside the images (in the folder; for a video, in its folder or ``<video>.yaml``);
see :func:`vslam.datasets.calibration.read_camera_yaml` (``width``/``height`` may be omitted: the first
image's size is used). Timestamps are ``index / fps``; ``fps`` from the argument, the YAML, the
video, or 30. Images are sorted by name with numbers compared numerically. No ground truth.
"""
from __future__ import annotations

import logging
from pathlib import Path
from typing import Iterator

import numpy as np

from vslam.datasets.base import CorruptFrameError, Dataset, list_images, load_image, read_camera_yaml, require_dir
from vslam.datasets.frame import Frame
from vslam.errors import CalibrationError, DatasetError
from vslam.geometry.camera import PinholeCamera

log = logging.getLogger(__name__)
DEFAULT_FPS = 30.0


def _resolve_camera(
    camera: PinholeCamera | str | Path | None, candidates: list[Path], size: tuple[int, int], where: Path
) -> tuple[PinholeCamera, dict]:
    if isinstance(camera, PinholeCamera):
        return camera, {}
    if camera is not None:
        return read_camera_yaml(camera, size)
    for cand in candidates:
        if cand.is_file():
            return read_camera_yaml(cand, size)
    raise CalibrationError(
        f"{where}: no camera calibration; add {candidates[0]} with fx, fy, cx, cy, width, height "
        f"(optional dist, fps) or pass a camera file"
    )


class FolderDataset(Dataset):
    """Images in one folder, in name order."""

    kind = "folder"

    def __init__(
        self,
        path: str | Path,
        sensor: str | None = None,
        camera: PinholeCamera | str | Path | None = None,
        fps: float | None = None,
    ) -> None:
        super().__init__()
        self.root = root = require_dir(path, "image folder")
        self.name = root.name
        self.sensors = ("mono",)
        self.sensor = self._select_sensor(sensor, "mono", {
            "stereo": "a folder of images is mono only", "rgbd": "a folder of images has no depth",
        })
        self._files = list_images(root)
        if not self._files:
            raise DatasetError(f"{root}: no image files ({', '.join(('png', 'jpg', 'bmp', 'tif'))})")
        first = load_image(self._files[0])
        self.camera, extras = _resolve_camera(camera, [root / "camera.yaml"], (first.shape[1], first.shape[0]), root)
        self.frame_rate = float(fps or extras.get("fps", DEFAULT_FPS))
        if self.frame_rate <= 0:
            raise DatasetError(f"fps must be positive, got {self.frame_rate}")
        self._timestamps = np.arange(len(self._files)) / self.frame_rate

    def _load(self, i: int) -> Frame:
        path = self._files[i]
        image = load_image(path)
        self._check_size(image, path)
        return Frame(index=i, timestamp=float(self._timestamps[i]), image=image, camera=self.camera, path=str(path))


class VideoDataset(Dataset):
    """Frames of a video file (decoded with OpenCV). ``len`` is the container's frame count."""

    kind = "video"

    def __init__(
        self,
        path: str | Path,
        sensor: str | None = None,
        camera: PinholeCamera | str | Path | None = None,
        fps: float | None = None,
    ) -> None:
        import cv2

        super().__init__()
        path = Path(path)
        if not path.is_file():
            raise DatasetError(f"{path}: video file not found")
        self.root = self.path = path
        self.name = path.stem
        self.sensors = ("mono",)
        self.sensor = self._select_sensor(sensor, "mono", {
            "stereo": "a video is mono only", "rgbd": "a video has no depth",
        })
        cap = cv2.VideoCapture(str(path))
        try:
            if not cap.isOpened():
                raise DatasetError(f"{path}: OpenCV cannot open this video; convert it to mp4 (H.264) or extract images")
            n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
            vfps = float(cap.get(cv2.CAP_PROP_FPS) or 0.0)
            ok, first = cap.read()
        finally:
            cap.release()
        if not ok or first is None:
            raise DatasetError(f"{path}: the first video frame cannot be decoded; the file is damaged or empty")
        size = (first.shape[1], first.shape[0])
        self.camera, extras = _resolve_camera(
            camera, [path.parent / "camera.yaml", path.with_suffix(".yaml")], size, path
        )
        self.frame_rate = float(fps or extras.get("fps") or (vfps if vfps > 0 else DEFAULT_FPS))
        self._timestamps = np.arange(max(n, 1)) / self.frame_rate

    def _load(self, i: int) -> Frame:
        import cv2

        cap = cv2.VideoCapture(str(self.path))
        try:
            cap.set(cv2.CAP_PROP_POS_FRAMES, i)
            ok, image = cap.read()
        finally:
            cap.release()
        if not ok:
            raise CorruptFrameError(f"{self.path}: video frame {i} cannot be decoded")
        return self._frame(i, image)

    def _frame(self, i: int, image: np.ndarray) -> Frame:
        self._check_size(image, self.path)
        return Frame(index=i, timestamp=float(self._timestamps[i]), image=image, camera=self.camera, path=str(self.path))

    def frames(self, start: int = 0, stop: int | None = None) -> Iterator[Frame]:
        """Decode sequentially (seeking once); stops early if the container held fewer frames."""
        import cv2

        n = len(self)
        stop = n if stop is None else min(stop, n)
        cap = cv2.VideoCapture(str(self.path))
        try:
            if start > 0:
                cap.set(cv2.CAP_PROP_POS_FRAMES, start)
            for i in range(start, stop):
                ok, image = cap.read()
                if not ok:
                    if i == start:
                        raise DatasetError(f"{self.path}: video frame {i} cannot be decoded")
                    log.warning("%s: video ended at frame %d of %d announced", self.path, i, n)
                    return
                yield self._frame(i, image)
        finally:
            cap.release()
