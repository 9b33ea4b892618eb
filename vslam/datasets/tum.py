"""TUM RGB-D benchmark sequences (Sturm et al., IROS 2012), plus our stereo/camera extensions.

Layout: ``rgb.txt`` and ``depth.txt`` (``timestamp filename`` lists), ``rgb/*.png``,
``depth/*.png`` (16-bit, metres = value / 5000), ``groundtruth.txt`` (TUM trajectory, ~100 Hz),
optionally ``associate.txt`` (``t_rgb rgb t_depth depth``), which is used when present; otherwise
rgb and depth are matched like TUM's ``associate.py`` (:func:`vslam.trajectory.associate_timestamps`,
max difference 0.02 s).

Calibration, in order: the ``camera`` argument; ``camera.yaml`` in the sequence folder (see
:func:`vslam.datasets.calibration.read_camera_yaml`); the freiburg1/2/3 preset chosen from the folder
name (``freiburg1``/``fr1`` ...); an ORB-SLAM style ``TUM*.yaml`` in the folder. Otherwise
:class:`CalibrationError`.

Extensions used by our synthetic sequences: ``right.txt`` (same format as ``rgb.txt``, listing
``right/<ts>.png`` at the rgb timestamps) makes ``stereo`` available; the baseline comes from
``camera.yaml``. ``camera.yaml`` may set ``depth_scale`` (PNG units per metre) and ``fps``.

Sensors: ``mono`` reads every image of ``rgb.txt``; ``rgbd`` reads the associated rgb/depth pairs;
``stereo`` reads rgb frames that have a right image. The default is ``rgbd`` when depth exists,
else ``stereo`` when available, else ``mono``.
"""
from __future__ import annotations

import logging
import re
from pathlib import Path

import numpy as np

from vslam.datasets.base import (
    CorruptFrameError,
    Dataset,
    check_timestamps,
    interpolate_poses,
    load_depth,
    load_image,
    read_camera_yaml,
    read_timestamped_list,
    require_dir,
)
from vslam.datasets.frame import Frame
from vslam.errors import CalibrationError, DatasetError
from vslam.trajectory import associate_timestamps, read_tum
from vslam.geometry.camera import PinholeCamera

log = logging.getLogger(__name__)

#: TUM RGB-D calibrations (https://cvg.cit.tum.de/data/datasets/rgbd-dataset/file_formats), 640x480.
TUM_PRESETS: dict[int, PinholeCamera] = {
    1: PinholeCamera(517.306408, 516.469215, 318.643040, 255.313989, 640, 480,
                     (0.262383, -0.953104, -0.005358, 0.002628, 1.163314)),
    2: PinholeCamera(520.908620, 521.007327, 325.141442, 249.701764, 640, 480,
                     (0.231222, -0.784899, -0.003257, -0.000105, 0.917205)),
    3: PinholeCamera(535.4, 539.2, 320.1, 247.6, 640, 480),
}
TUM_DEPTH_SCALE = 5000.0
_PRESET_RE = re.compile(r"(?:freiburg|fr)_?([123])(?![0-9])", re.IGNORECASE)


def tum_preset_from_name(name: str) -> int | None:
    """The freiburg number (1, 2, 3) named in a folder name, or None."""
    m = _PRESET_RE.search(name)
    return int(m.group(1)) if m else None


def _check_files(root: Path, rel: list[str], what: str) -> None:
    """Cheap existence check at open time: fatal when the first or more than 10% are missing."""
    missing = [r for r in rel if not (root / r).is_file()]
    if not missing:
        return
    if not (root / rel[0]).is_file() or len(missing) > 0.1 * len(rel):
        raise DatasetError(
            f"{root / missing[0]}: {len(missing)} of {len(rel)} {what} files listed are missing; "
            f"re-extract the sequence or fix the list"
        )
    log.warning("%s: %d %s files listed are missing; those frames will be skipped", root, len(missing), what)


def _read_rgb_list(rgb_path: Path) -> tuple[np.ndarray | None, list[str] | None]:
    """The mono list, every rgb image: ``(timestamps, files)``, or ``(None, None)`` without rgb.txt
    (then filled from associate.txt)."""
    if not rgb_path.is_file():
        return None, None
    t_rgb, rows = read_timestamped_list(rgb_path, "rgb list")
    check_timestamps(t_rgb, rgb_path)
    return t_rgb, [r[0] for r in rows]


def _rgbd_pairs(assoc_path: Path, depth_path: Path, rgb_path: Path, t_rgb, rgb_files, max_difference: float):
    """The rgb-depth pairs ``(t_rgb, rgb files, t_depth, depth files)`` from associate.txt, else
    depth.txt associated to rgb.txt within ``max_difference`` s, else None; returned with the mono
    list (from associate.txt when there was no rgb.txt)."""
    rgbd = None
    if assoc_path.is_file():
        t_a, rows = read_timestamped_list(assoc_path, "association file", min_columns=4)
        check_timestamps(t_a, assoc_path)
        try:
            t_d = np.array([float(r[1]) for r in rows])
        except ValueError:
            raise DatasetError(f"{assoc_path}: columns must be 't_rgb rgb t_depth depth'") from None
        rgbd = (t_a, [r[0] for r in rows], t_d, [r[2] for r in rows])
        if t_rgb is None:
            t_rgb, rgb_files = t_a, [r[0] for r in rows]
    elif depth_path.is_file():
        t_dl, drows = read_timestamped_list(depth_path, "depth list")
        check_timestamps(t_dl, depth_path)
        pairs = np.column_stack(associate_timestamps(t_rgb, t_dl, max_difference))
        if len(pairs) == 0:
            raise DatasetError(
                f"{depth_path}: no depth timestamp is within {max_difference} s of an rgb timestamp "
                f"in {rgb_path}; the lists do not belong together"
            )
        rgbd = (t_rgb[pairs[:, 0]], [rgb_files[i] for i in pairs[:, 0]],
                t_dl[pairs[:, 1]], [drows[j][0] for j in pairs[:, 1]])
    return rgbd, t_rgb, rgb_files


def _stereo_pairs(right_path: Path, rgb_path: Path, t_rgb, rgb_files):
    """The stereo pairs ``(t, left files, right files)`` from right.txt (an extension), or None."""
    if not right_path.is_file():
        return None
    t_r, rrows = read_timestamped_list(right_path, "right image list")
    check_timestamps(t_r, right_path)
    pairs = np.column_stack(associate_timestamps(t_rgb, t_r, 1e-3))
    if len(pairs) == 0:
        raise DatasetError(f"{right_path}: no right timestamp matches an rgb timestamp of {rgb_path}")
    return t_rgb[pairs[:, 0]], [rgb_files[i] for i in pairs[:, 0]], [rrows[j][0] for j in pairs[:, 1]]


class TumDataset(Dataset):
    """A TUM RGB-D sequence folder."""

    kind = "tum"

    def __init__(
        self,
        path: str | Path,
        sensor: str | None = None,
        camera: PinholeCamera | str | Path | None = None,
        max_difference: float = 0.02,
        gt_max_gap: float = 0.1,
    ) -> None:
        super().__init__()
        self.root = root = require_dir(path, "TUM sequence folder")
        self.name = root.name
        assoc_path, rgb_path, depth_path, right_path = (
            root / "associate.txt", root / "rgb.txt", root / "depth.txt", root / "right.txt"
        )
        if not rgb_path.is_file() and not assoc_path.is_file():
            raise DatasetError(f"{rgb_path}: not found; a TUM sequence needs rgb.txt (timestamp filename per line)")

        t_rgb, rgb_files = _read_rgb_list(rgb_path)
        rgbd, t_rgb, rgb_files = _rgbd_pairs(assoc_path, depth_path, rgb_path, t_rgb, rgb_files, max_difference)
        stereo = _stereo_pairs(right_path, rgb_path, t_rgb, rgb_files)

        self.sensors = tuple(s for s, ok in (("mono", True), ("stereo", stereo is not None), ("rgbd", rgbd is not None)) if ok)
        default = "rgbd" if rgbd is not None else ("stereo" if stereo is not None else "mono")
        self.sensor = self._select_sensor(sensor, default, {
            "rgbd": "no depth.txt or associate.txt in the folder",
            "stereo": "no right.txt in the folder",
        })

        self._use_lists(rgbd, stereo, t_rgb, rgb_files)
        self.camera, extras = self._calibration(camera)
        self.depth_scale = float(extras.get("depth_scale", TUM_DEPTH_SCALE))
        self.frame_rate = float(extras.get("fps", 30.0))
        if self.sensor == "stereo" and not self.camera.baseline:
            raise CalibrationError(
                f"{root / 'camera.yaml'}: stereo needs the baseline; add 'baseline: <metres>' to camera.yaml"
            )
        self._gt_file = root / "groundtruth.txt"
        self._gt_max_gap = gt_max_gap

    def _use_lists(self, rgbd, stereo, t_rgb, rgb_files) -> None:
        """Timestamps and files of the selected sensor (checked to exist, missing ones warned about)."""
        root = self.root
        self._depth_files: list[str] | None = None
        self._right_files: list[str] | None = None
        if self.sensor == "rgbd":
            self._timestamps, self._rgb_files, _, self._depth_files = rgbd  # type: ignore[misc]
            self._timestamps = np.asarray(self._timestamps)
        elif self.sensor == "stereo":
            self._timestamps, self._rgb_files, self._right_files = stereo  # type: ignore[misc]
        else:
            self._timestamps, self._rgb_files = np.asarray(t_rgb), list(rgb_files)
        _check_files(root, self._rgb_files, "image")
        if self._depth_files is not None:
            _check_files(root, self._depth_files, "depth")
        if self._right_files is not None:
            _check_files(root, self._right_files, "right image")

    # ------------------------------------------------------------------------------------------
    def _calibration(self, camera: PinholeCamera | str | Path | None) -> tuple[PinholeCamera, dict]:
        from vslam.datasets.calibration import read_pinhole_calibration

        root = self.root
        if isinstance(camera, PinholeCamera):
            self.calibration_source = "the given camera"
            return camera, {}

        def first_size() -> tuple[int, int]:
            img = load_image(root / self._rgb_files[0])
            return img.shape[1], img.shape[0]

        yaml_path = Path(camera) if camera is not None else root / "camera.yaml"
        if camera is not None or yaml_path.is_file():
            source = camera if camera is not None else yaml_path
            try:
                cal = read_pinhole_calibration(source, reader="the TUM reader")
            except CalibrationError as exc:
                if "lacks 'width'" not in str(exc) and "lacks 'height'" not in str(exc) \
                        and "has no image size" not in str(exc) and "'Camera.width'" not in str(exc):
                    raise
                cal = read_pinhole_calibration(source, first_size(), reader="the TUM reader")
            self.calibration_source = cal.describe()
            return cal.camera, cal.extras
        preset = tum_preset_from_name(root.name)
        named = root.name
        if preset is None and root.parent != root:
            preset = tum_preset_from_name(root.parent.name)
            named = root.parent.name
        if preset is not None:
            self.calibration_source = (
                f"TUM freiburg{preset} preset, chosen from the folder name {named!r} "
                f"(override with --camera fr1|fr2|fr3 or a camera file)"
            )
            log.info("%s: using the %s", root, self.calibration_source)
            return TUM_PRESETS[preset], {"depth_scale": TUM_DEPTH_SCALE}
        for cand in sorted(root.glob("TUM*.yaml")):
            size = first_size()
            self.calibration_source = str(cand)
            return read_camera_yaml(cand, size)
        raise CalibrationError(
            f"{root}: no calibration: the folder name names no TUM camera (freiburg1/2/3 or fr1/2/3) "
            f"and there is no camera.yaml; pass --camera FILE or --camera fr1|fr2|fr3, or add camera.yaml "
            f"with fx, fy, cx, cy, width, height (optional dist, baseline, depth_scale, fps)"
        )

    def _gt_poses(self):
        if not self._gt_file.is_file():
            return None
        gt = read_tum(self._gt_file, duplicates="keep_last")  # fr2/desk repeats some: keep the last, as evo
        return interpolate_poses(gt, self._timestamps, max_gap=self._gt_max_gap)

    def _load(self, i: int) -> Frame:
        path = self.root / self._rgb_files[i]
        image = load_image(path)
        self._check_size(image, path)
        depth = right = None
        if self._depth_files is not None:
            depth = load_depth(self.root / self._depth_files[i], self.depth_scale, image.shape[:2])
        if self._right_files is not None:
            right = load_image(self.root / self._right_files[i])
            if right.shape != image.shape:
                raise CorruptFrameError(
                    f"{self.root / self._right_files[i]}: right image is {right.shape} but left is {image.shape}"
                )
        return Frame(
            index=i, timestamp=float(self._timestamps[i]), image=image, camera=self.camera,
            image_right=right, depth=depth, T_world_cam=self.gt_pose(i), path=str(path),
        )
