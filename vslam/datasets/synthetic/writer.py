"""Write a synthetic sequence to disk in TUM RGB-D layout (plus our stereo extension).

Layout (read back by :mod:`vslam.datasets.tum`)::

    rgb/<ts>.png  rgb.txt          left colour images
    right/<ts>.png  right.txt      right images of the rectified pair (same timestamps)
    depth/<ts>.png  depth.txt      uint16, metres * depth_scale (5000), 0 = invalid
    groundtruth.txt                TUM ``timestamp tx ty tz qx qy qz qw`` (T_world_cam)
    camera.yaml                    fx fy cx cy width height dist baseline depth_scale fps

With ``imu=SyntheticImuConfig(...)`` (opt-in; the default output is unchanged) also, in EuRoC layout
(:mod:`vslam.datasets.synthetic.imu`)::

    imu0/data.csv                  #timestamp [ns], w_RS_S xyz [rad/s], a_RS_S xyz [m/s^2] (IMU frame)
    imu0/sensor.yaml               EuRoC IMU sensor.yaml: noise densities, random walks, rate_hz, and
                                   T_BS = T_cam_imu (the "body" is the camera of groundtruth.txt)
    imu0/camchain-imucam.yaml      Kalibr: cam0 T_cam_imu, timeshift_cam_imu 0
    imu0/groundtruth.csv           EuRoC state_groundtruth_estimate0 columns for the IMU: p, q (wxyz),
                                   v (world), b_w, b_a at every sample

``vslam.datasets.imu.read_imu_calibration([imu0/sensor.yaml, imu0/camchain-imucam.yaml])`` reads the
calibration back; ``load_imu_csv(imu0/data.csv)`` the samples.
"""
from __future__ import annotations

import logging
from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Callable

import cv2
import numpy as np
import yaml

from vslam.datasets.synthetic.imu import SyntheticImuConfig, write_imu
from vslam.datasets.synthetic.sequence import SyntheticConfig, SyntheticSequence
from vslam.errors import DatasetError
from vslam.trajectory import write_tum

log = logging.getLogger(__name__)

DEPTH_SCALE = 5000.0


def depth_to_png(depth: np.ndarray, scale: float = DEPTH_SCALE) -> np.ndarray:
    """float32 metres -> uint16 ``round(depth * scale)``; 0 (invalid) where out of the 16-bit range."""
    raw = np.rint(depth.astype(np.float64) * scale)
    raw[(raw > 65535) | ~np.isfinite(raw) | (raw < 0)] = 0
    return raw.astype(np.uint16)


def _list_header(what: str) -> str:
    return f"# {what}\n# synthetic sequence written by vslam\n# timestamp filename\n"


def write_camera_yaml(path: Path, config: SyntheticConfig) -> None:
    data = {
        "fx": float(config.fx), "fy": float(config.fy), "cx": float(config.cx), "cy": float(config.cy),
        "width": int(config.width), "height": int(config.height), "dist": [0.0, 0.0, 0.0, 0.0, 0.0],
        "baseline": float(config.baseline), "depth_scale": DEPTH_SCALE, "fps": float(config.fps),
    }
    with open(path, "w") as fh:
        yaml.safe_dump(data, fh, sort_keys=False)


def render_sequence(
    out_dir: str | Path,
    config: SyntheticConfig = SyntheticConfig(),
    progress: Callable[[int], None] | None = None,
    imu: SyntheticImuConfig | None = None,
    sequence: SyntheticSequence | None = None,
) -> Path:
    """Render ``config`` into ``out_dir`` (created) in TUM layout and return ``out_dir``.

    ``imu``: also write the synthetic IMU in ``imu0/`` (module docstring).

    ``sequence``: the frames to write (default ``SyntheticSequence(config)``; e.g. a fleet session
    along its own poses, :mod:`vslam.datasets.synthetic.fleet`), rendered with ``config``.

    ``progress(n)`` is called after each frame with the number of frames done (e.g. a tqdm update).
    """
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
        for sub in ("rgb",) + (("depth",) if config.rgbd else ()) + (("right",) if config.stereo else ()):
            (out / sub).mkdir(exist_ok=True)
    except OSError as exc:
        raise DatasetError(f"{out}: cannot create the output folder ({exc.strerror}); choose another path") from None
    seq = SyntheticSequence(config) if sequence is None else sequence
    lists: dict[str, list[str]] = {"rgb": [], "depth": [], "right": []}
    # PNG encoding (which releases the GIL) runs on two threads while the next frame renders
    pending: deque[Future] = deque()
    with ThreadPoolExecutor(max_workers=2) as pool:
        for frame in seq:
            name = f"{frame.timestamp:.6f}"
            jobs = [("rgb", frame.image)]
            if frame.depth is not None:
                jobs.append(("depth", depth_to_png(frame.depth)))
            if frame.image_right is not None:
                jobs.append(("right", frame.image_right))
            for key, img in jobs:
                pending.append(pool.submit(_imwrite, out / key / f"{name}.png", img))
                lists[key].append(f"{name} {key}/{name}.png\n")
            while len(pending) > 12:
                pending.popleft().result()
            if progress is not None:
                progress(frame.index + 1)
        while pending:
            pending.popleft().result()
    titles = {"rgb": "color images", "depth": "depth maps", "right": "right images (rectified stereo)"}
    for key, lines in lists.items():
        if lines:
            (out / f"{key}.txt").write_text(_list_header(titles[key]) + "".join(lines))
    write_tum(out / "groundtruth.txt", seq.ground_truth())
    write_camera_yaml(out / "camera.yaml", config)
    if imu is not None:
        write_imu(out / "imu0", config, imu)
    log.info("synthetic sequence: %d frames written to %s", len(seq), out)
    return out


def _imwrite(path: Path, image: np.ndarray) -> None:
    # fast PNG compression: the files are test data, size matters less than speed
    params = [cv2.IMWRITE_PNG_COMPRESSION, 1, cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_SUB]
    if not cv2.imwrite(str(path), image, params):
        raise DatasetError(f"{path}: cannot write the image; check disk space and permissions")
