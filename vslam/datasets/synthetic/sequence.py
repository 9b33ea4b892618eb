"""Synthetic sequences in memory: configuration, sensor noise, and :class:`Frame` records.

Every frame is rendered on demand from its exact pose; all randomness (pixel noise, depth noise,
missing depth) comes from ``np.random.default_rng([seed, index])``, so frame ``i`` is the same
bytes whatever order frames are requested in, and two sequences with the same config are identical.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Iterator

import cv2
import numpy as np

from vslam.datasets.frame import Frame
from vslam.datasets.synthetic.renderer import Renderer, default_renderer
from vslam.datasets.synthetic.trajectory import make_path
from vslam.errors import ConfigError
from vslam.trajectory import Trajectory
from vslam.geometry.camera import PinholeCamera

PATH_KINDS = ("loop", "forward")
DEPTH_NOISE_MODELS = ("constant", "proportional")
MISSING_DEPTH_MODES = ("pixels", "blobs")


@dataclass(frozen=True)
class SyntheticConfig:
    """What to render. Distances in metres, noise in 8-bit intensity levels.

    Attributes:
        n_frames: number of frames; ``fps`` sets the timestamps ``start_time + i / fps``.
        width, height, fx, fy, cx, cy: pinhole intrinsics (no distortion).
        baseline: stereo baseline; the right camera sits at ``+baseline`` along the left x axis.
        path: ``"loop"`` (ellipse round the room, last pose == first) or ``"forward"``.
        laps: loop path only: number of laps (``> 1`` revisits the start mid-sequence).
        stereo, rgbd: also render the right image / the depth map.
        pixel_noise: std of Gaussian noise added to every intensity (0 = none).
        depth_noise: std of Gaussian depth noise, metres (``"constant"``) or a fraction of the
            depth (``"proportional"``: ``sigma = depth_noise * z``).
        missing_depth: fraction of depth pixels set to 0 (invalid), isolated ``"pixels"`` or ``"blobs"``.
        seed: seeds all noise.
    """

    n_frames: int = 300
    width: int = 640
    height: int = 480
    fx: float = 525.0
    fy: float = 525.0
    cx: float = 319.5
    cy: float = 239.5
    baseline: float = 0.1
    path: str = "loop"
    laps: float = 1.0
    stereo: bool = True
    rgbd: bool = True
    pixel_noise: float = 0.0
    depth_noise: float = 0.0
    depth_noise_model: str = "constant"
    missing_depth: float = 0.0
    missing_depth_mode: str = "pixels"
    seed: int = 0
    fps: float = 30.0
    start_time: float = 0.0

    def __post_init__(self) -> None:
        if self.n_frames < 1:
            raise ConfigError(f"synthetic n_frames must be >= 1, got {self.n_frames}")
        if self.width < 8 or self.height < 8:
            raise ConfigError(f"synthetic image size {self.width}x{self.height} is too small")
        if self.path not in PATH_KINDS:
            raise ConfigError(f"synthetic path {self.path!r} unknown; use one of {PATH_KINDS}")
        if self.depth_noise_model not in DEPTH_NOISE_MODELS:
            raise ConfigError(f"depth_noise_model {self.depth_noise_model!r} unknown; use one of {DEPTH_NOISE_MODELS}")
        if self.missing_depth_mode not in MISSING_DEPTH_MODES:
            raise ConfigError(f"missing_depth_mode {self.missing_depth_mode!r} unknown; use one of {MISSING_DEPTH_MODES}")
        if not 0.0 <= self.missing_depth < 1.0:
            raise ConfigError(f"missing_depth is a fraction in [0, 1), got {self.missing_depth}")
        if self.pixel_noise < 0 or self.depth_noise < 0 or self.fps <= 0 or self.baseline <= 0:
            raise ConfigError("pixel_noise, depth_noise must be >= 0 and fps, baseline > 0")

    @property
    def camera(self) -> PinholeCamera:
        """The left camera (with ``baseline`` set)."""
        return PinholeCamera(self.fx, self.fy, self.cx, self.cy, self.width, self.height, baseline=self.baseline)

    def timestamps(self) -> np.ndarray:
        """Frame times, rounded to the microsecond (what the TUM files store)."""
        return np.round(self.start_time + np.arange(self.n_frames) / self.fps, 6)


def right_from_left(T_world_cam: np.ndarray, baseline: float) -> np.ndarray:
    """``T_world_right = T_world_cam T_cam_right`` with the right camera at ``+baseline`` on x."""
    T_cam_right = np.eye(4)
    T_cam_right[0, 3] = baseline
    return np.asarray(T_world_cam) @ T_cam_right


def _gaussian(shape: tuple[int, ...], sigma: float, rng: np.random.Generator) -> np.ndarray:
    """float32 ``N(0, sigma^2)`` samples from OpenCV's fast generator, seeded from ``rng``."""
    out = np.empty(shape, np.float32)
    cv2.setRNGSeed(int(rng.integers(1, 2**31 - 1)))
    cv2.randn(out.reshape(shape[0], -1), 0.0, float(sigma))
    return out


def add_pixel_noise(image: np.ndarray, sigma: float, rng: np.random.Generator) -> np.ndarray:
    """``image + N(0, sigma^2)`` per intensity, rounded and clipped to ``uint8``."""
    if sigma <= 0:
        return image
    noise = _gaussian(image.shape, sigma, rng)
    return cv2.add(image.astype(np.float32), noise, dtype=cv2.CV_8U)


def add_depth_noise(depth: np.ndarray, sigma: float, model: str, rng: np.random.Generator) -> np.ndarray:
    """Gaussian depth noise, ``sigma`` metres or ``sigma * z`` (proportional); invalid (0) stays 0."""
    if sigma <= 0:
        return depth
    noise = _gaussian(depth.shape, sigma, rng)
    if model == "proportional":
        noise *= depth
    out = depth + noise
    out[(depth <= 0) | (out < 0)] = 0.0
    return out


def missing_depth_mask(shape: tuple[int, int], fraction: float, mode: str, rng: np.random.Generator) -> np.ndarray:
    """Boolean mask of exactly ``round(fraction * H * W)`` pixels to invalidate.

    ``"pixels"``: uniformly random pixels. ``"blobs"``: the highest values of a smoothed random
    field (Gaussian blur, sigma = 1/40 of the image width), i.e. irregular connected holes.
    Ties in the field are broken by index, so the count is exact.
    """
    n = int(round(fraction * shape[0] * shape[1]))
    mask = np.zeros(shape[0] * shape[1], bool)
    if n == 0:
        return mask.reshape(shape)
    if mode == "pixels":
        mask[rng.choice(mask.size, size=n, replace=False)] = True
    else:
        # smooth random field: white noise at 1/8 resolution, blurred, upsampled
        small = (max(shape[0] // 8, 2), max(shape[1] // 8, 2))
        field = cv2.GaussianBlur(rng.standard_normal(small, dtype=np.float32), (0, 0), max(small[1] / 40.0, 0.5))
        field = cv2.resize(field, (shape[1], shape[0]), interpolation=cv2.INTER_CUBIC)
        mask[np.argpartition(field.ravel(), mask.size - n)[mask.size - n:]] = True
    return mask.reshape(shape)


class SyntheticSequence:
    """An in-memory synthetic sequence: ``len(seq)``, ``seq[i]`` and iteration yield :class:`Frame`.

    Duck-compatible with :class:`vslam.datasets.base.Dataset` (``camera``, ``sensors``, ``sensor``,
    ``frame_rate``, ``timestamps``, ``frames(start, stop)``, ``ground_truth()``, ``skipped``).

    Example:
        >>> seq = SyntheticSequence(SyntheticConfig(n_frames=5, stereo=False))
        >>> frame = seq[0]
        >>> frame.image.shape, frame.depth.dtype, frame.T_world_cam.shape
        ((480, 640, 3), dtype('float32'), (4, 4))
    """

    def __init__(self, config: SyntheticConfig = SyntheticConfig(), renderer: Renderer | None = None):
        self.config = config
        self.renderer = renderer if renderer is not None else default_renderer()
        self.camera = config.camera
        self.T_world_cam = make_path(config.path, config.n_frames, config.laps)
        self.timestamps = config.timestamps()
        self.name = f"synthetic-{config.path}"
        self.kind = "synthetic"
        self.frame_rate = float(config.fps)
        self.sensors = ("mono",) + (("stereo",) if config.stereo else ()) + (("rgbd",) if config.rgbd else ())
        self.sensor = self.sensors[-1]
        self.skipped = 0

    def __len__(self) -> int:
        return self.config.n_frames

    def __iter__(self) -> Iterator[Frame]:
        return self.frames()

    def frames(self, start: int = 0, stop: int | None = None) -> Iterator[Frame]:
        """Render frames ``start .. stop-1`` one at a time."""
        for i in range(start, len(self) if stop is None else min(stop, len(self))):
            yield self[i]

    def __getitem__(self, index: int) -> Frame:
        n = len(self)
        if not -n <= index < n:
            raise IndexError(f"frame {index} out of range for a {n}-frame synthetic sequence")
        i = index % n
        cfg = self.config
        rng = np.random.default_rng([cfg.seed, i])
        T_world_cam = self.T_world_cam[i]
        image, depth = self.renderer.render(T_world_cam, self.camera)
        image = add_pixel_noise(image, cfg.pixel_noise, rng)
        right = None
        if cfg.stereo:
            right, _ = self.renderer.render(right_from_left(T_world_cam, cfg.baseline), self.camera)
            right = add_pixel_noise(right, cfg.pixel_noise, rng)
        if cfg.rgbd:
            depth = add_depth_noise(depth, cfg.depth_noise, cfg.depth_noise_model, rng)
            if cfg.missing_depth > 0:
                depth[missing_depth_mask(depth.shape, cfg.missing_depth, cfg.missing_depth_mode, rng)] = 0.0
        else:
            depth = None
        return Frame(
            index=i, timestamp=float(self.timestamps[i]), image=image, camera=self.camera,
            image_right=right, depth=depth, T_world_cam=T_world_cam.copy(), path=f"synthetic:{i}",
        )

    def ground_truth(self) -> Trajectory:
        """The exact ``T_world_cam`` trajectory at the frame timestamps."""
        return Trajectory(self.timestamps.copy(), self.T_world_cam.copy())
