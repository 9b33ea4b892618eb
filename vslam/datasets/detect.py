"""Open any supported sequence: :func:`open_dataset` detects the format from the path.

Detection (first match wins):

* a ROS 1 ``.bag`` file or a ROS 2 bag folder (``metadata.yaml``) -> ``rosbag``
* a file with a video extension -> ``video``
* ``rgb.txt`` or ``associate.txt`` in the folder -> ``tum``
* ``mav0/`` in the folder, or the folder is ``mav0`` (``cam0/data.csv``) -> ``euroc``
* ``image_0/`` + ``times.txt`` -> ``kitti`` (a KITTI root with ``sequences/`` holding exactly one
  sequence is accepted too)
* ``seq-*`` folders or ``frame-*.color.*`` files -> ``7scenes``
* image files -> ``folder``

``camera:N`` and stream URLs (``rtsp://``, ``http://`` ...) are not paths: they open a live
source (:class:`~vslam.datasets.live.LiveDataset`, ``live``).
"""
from __future__ import annotations

from pathlib import Path

from vslam.datasets.base import IMAGE_EXTENSIONS, Dataset
from vslam.errors import DatasetError

KINDS = ("tum", "kitti", "euroc", "7scenes", "folder", "video", "rosbag", "live")
VIDEO_EXTENSIONS = (".mp4", ".avi", ".mov", ".mkv", ".webm", ".m4v", ".mpg", ".mpeg", ".wmv")
_ALIASES = {"bag": "rosbag", "ros": "rosbag", "sevenscenes": "7scenes", "7-scenes": "7scenes", "images": "folder", "tum_rgbd": "tum", "asl": "euroc"}


def detect_kind(path: str | Path) -> str:
    """The dataset kind of ``path`` (one of :data:`KINDS`), or raise :class:`DatasetError`."""
    path = Path(path)
    if not path.exists():
        raise DatasetError(f"{path}: no such file or folder; check the dataset path")
    if (path.is_file() and path.suffix == ".bag") or (path.is_dir() and (path / "metadata.yaml").is_file()):
        return "rosbag"
    if path.is_file():
        if path.suffix.lower() in VIDEO_EXTENSIONS:
            return "video"
        raise DatasetError(
            f"{path}: is a file but not a video ({', '.join(VIDEO_EXTENSIONS)}); pass the sequence folder"
        )
    if (path / "rgb.txt").is_file() or (path / "associate.txt").is_file():
        return "tum"
    if (path / "mav0").is_dir() or (path / "cam0" / "data.csv").is_file():
        return "euroc"
    if (path / "image_0").is_dir():
        return "kitti"
    if (path / "sequences").is_dir():
        return "kitti"
    if any(path.glob("seq-*")) or any(path.glob("frame-*.color.*")):
        return "7scenes"
    if any(p.suffix.lower() in IMAGE_EXTENSIONS for p in path.iterdir()):
        return "folder"
    raise DatasetError(
        f"{path}: unrecognised dataset layout (looked for TUM rgb.txt, EuRoC mav0/, KITTI image_0/, "
        f"7-Scenes seq-*/, or image files); pass --dataset to force a format"
    )


def _kitti_sequence(path: Path) -> Path:
    seqs = path / "sequences"
    if (path / "image_0").is_dir() or not seqs.is_dir():
        return path
    found = sorted(p for p in seqs.iterdir() if (p / "image_0").is_dir())
    if len(found) == 1:
        return found[0]
    names = ", ".join(p.name for p in found) or "none"
    raise DatasetError(f"{path}: holds KITTI sequences ({names}); pass one sequence folder, e.g. {seqs}/NN")


def open_dataset(
    path: str | Path,
    kind: str | None = None,
    sensor: str | None = None,
    camera=None,
    **options,
) -> Dataset:
    """Open a sequence for streaming :class:`~vslam.datasets.frame.Frame` records.

    Args:
        path: the sequence folder (or a video file, or a live source ``camera:0`` / ``rtsp://...``).
        kind: force the format: ``tum``, ``kitti``, ``euroc``, ``7scenes``, ``folder``, ``video``,
            ``rosbag``, ``live`` (detected from the path when None).
        sensor: ``mono``, ``stereo`` or ``rgbd``; None picks the richest the data has.
        camera: a :class:`~vslam.geometry.camera.PinholeCamera` or a camera YAML path overriding the
            calibration (TUM, folder, video).
        options: passed to the reader (e.g. ``fps`` for folder/video, ``max_difference`` for TUM).

    Example:
        >>> ds = open_dataset("../shared/data/kitti_odometry/sequences/06")  # doctest: +SKIP
        >>> len(ds), ds.sensor, ds.camera.baseline  # doctest: +SKIP
        (51, 'stereo', 0.53716...)
    """
    from vslam.datasets.live import is_live_source

    if kind == "live" or (kind is None and is_live_source(str(path))):
        from vslam.datasets.live import LiveDataset

        return LiveDataset(str(path), sensor=sensor, camera=camera, **options)
    path = Path(path)
    if kind is None:
        kind = detect_kind(path)
    else:
        kind = _ALIASES.get(kind.lower(), kind.lower())
        if kind not in KINDS:
            raise DatasetError(f"unknown dataset kind {kind!r}; use one of {', '.join(KINDS)}")
        if not path.exists():
            raise DatasetError(f"{path}: no such file or folder; check the dataset path")
    if kind == "tum":
        from vslam.datasets.tum import TumDataset

        return TumDataset(path, sensor=sensor, camera=camera, **options)
    if kind == "kitti":
        from vslam.datasets.kitti import KittiDataset

        if camera is not None:
            raise DatasetError("KITTI calibration comes from calib.txt; do not pass a camera")
        return KittiDataset(_kitti_sequence(path), sensor=sensor, **options)
    if kind == "euroc":
        from vslam.datasets.euroc import EurocDataset

        if camera is not None:
            raise DatasetError("EuRoC calibration comes from sensor.yaml; do not pass a camera")
        return EurocDataset(path, sensor=sensor, **options)
    if kind == "7scenes":
        from vslam.datasets.sevenscenes import SevenScenesDataset

        return SevenScenesDataset(path, sensor=sensor, camera=camera, **options)
    if kind == "rosbag":
        from vslam.datasets.rosbag import RosbagDataset

        return RosbagDataset(path, sensor=sensor, camera=camera, **options)
    if kind == "folder":
        from vslam.datasets.folder import FolderDataset

        return FolderDataset(path, sensor=sensor, camera=camera, **options)
    from vslam.datasets.folder import VideoDataset

    return VideoDataset(path, sensor=sensor, camera=camera, **options)
