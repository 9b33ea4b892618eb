"""Training data for vocabularies: ORB descriptors from image folders, datasets or built-in samples.

ORB (Rublee et al., ICCV 2011) through ``cv2.ORB_create``, 1000 features per image by default, as
ORB-SLAM uses for its vocabulary.
"""
from __future__ import annotations

import functools
import logging
from pathlib import Path
from typing import Iterable, Iterator, Sequence

import numpy as np

from vslam.errors import DatasetError

log = logging.getLogger(__name__)

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".ppm", ".pgm", ".tif", ".tiff")

# scikit-image sample images that ship inside its wheel (no download) and carry natural texture.
DEFAULT_SAMPLE_IMAGES = (
    "astronaut", "brick", "camera", "cell", "chelsea", "clock", "coffee", "coins", "grass", "gravel",
    "hubble_deep_field", "immunohistochemistry", "microaneurysms", "moon", "page", "retina", "rocket",
    "text", "motorcycle_left", "motorcycle_right",
)


def extract_orb(image: np.ndarray, n_features: int = 1000) -> np.ndarray:
    """ORB descriptors ``(N, 32)`` uint8 of a grayscale or BGR ``uint8`` image (N <= n_features)."""
    import cv2

    if image.ndim == 3:
        image = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    orb = cv2.ORB_create(nfeatures=n_features)
    _, descriptors = orb.detectAndCompute(image, None)
    if descriptors is None:
        return np.zeros((0, 32), np.uint8)
    return descriptors


def image_paths(source: str | Path) -> list[Path]:
    """Image files of a folder (recursively, sorted) or the file itself."""
    source = Path(source)
    if source.is_file():
        return [source]
    if not source.is_dir():
        raise DatasetError(f"training source {source} is neither an image file nor a folder")
    return sorted(p for p in source.rglob("*") if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file())


def _open_dataset(source: Path):
    """The dataset at ``source`` through ``vslam.datasets.open_dataset`` (monocular), or None."""
    try:
        from vslam.datasets import open_dataset
    except ImportError:  # pragma: no cover - readers not installed
        return None
    try:
        return open_dataset(source, sensor="mono")
    except Exception as exc:  # unknown layout: fall back to globbing images
        log.debug("open_dataset(%s) failed (%s): globbing images instead", source, exc)
        return None


def iter_training_images(sources: Sequence[str | Path], every: int = 1, max_frames: int | None = None
                         ) -> Iterator[np.ndarray]:
    """Grayscale images from ``sources`` (datasets, image folders or files): every ``every``-th, at most ``max_frames``.

    A folder that :func:`vslam.datasets.open_dataset` recognises (TUM, KITTI, EuRoC, 7-Scenes) is
    read as a sequence (left/colour camera only); any other folder is searched recursively for images.
    """
    import cv2

    if every < 1:
        raise DatasetError(f"every={every}: the frame step must be >= 1")
    count = 0
    for source in sources:
        source = Path(source)
        dataset = _open_dataset(source) if source.is_dir() else None
        if dataset is not None:
            frames: Iterable[np.ndarray] = (dataset[i].gray for i in range(0, len(dataset), every))
        else:
            paths = image_paths(source)
            if not paths:
                raise DatasetError(f"training source {source} holds no images ({', '.join(IMAGE_SUFFIXES)})")
            frames = (_read_gray(p, cv2) for p in paths[::every])
        for image in frames:
            if max_frames is not None and count >= max_frames:
                return
            count += 1
            yield image


def _read_gray(path: Path, cv2) -> np.ndarray:
    image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if image is None:
        raise DatasetError(f"cannot read image {path}")
    return image


def descriptors_from_sources(sources: Sequence[str | Path], every: int = 1, max_frames: int | None = None,
                             n_features: int = 1000, progress=None) -> list[np.ndarray]:
    """One ORB descriptor array per selected training image. ``progress``: a tqdm-like factory
    (``progress(iterable, total=, desc=)``) wrapping the images; None shows nothing."""
    images = iter_training_images(sources, every, max_frames)
    if progress is not None:
        images = progress(images, total=max_frames, desc="ORB features", unit="image")
    return [extract_orb(img, n_features) for img in images]


@functools.lru_cache(maxsize=None)
def _sample_image(name: str) -> np.ndarray:
    """A scikit-image sample as ``uint8`` grayscale (cached, read-only)."""
    import cv2
    from skimage import data

    if name.startswith("motorcycle_"):
        left, right, _ = data.stereo_motorcycle()
        image = left if name.endswith("left") else right
    else:
        image = getattr(data, name)()
    image = np.asarray(image)
    if image.dtype != np.uint8:
        image = cv2.normalize(image.astype(np.float64), None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    if image.ndim == 3:
        image = cv2.cvtColor(image[..., :3], cv2.COLOR_RGB2GRAY)
    image = np.ascontiguousarray(image)
    image.flags.writeable = False
    return image


def default_training_images(views_per_image: int = 24, seed: int = 0) -> Iterator[np.ndarray]:
    """Deterministic views of the scikit-image sample photographs (no download).

    Each image is seen ``views_per_image`` times under a random (seeded) similarity + perspective
    warp: scale 0.6-2.0, rotation +-180 deg, corner jitter up to 12 % of the size, plus gamma and
    mild blur, rendered at 640x480 so the features look like those of a camera frame.
    """
    import cv2

    rng = np.random.default_rng(seed)
    out_w, out_h = 640, 480
    for name in DEFAULT_SAMPLE_IMAGES:
        try:
            image = _sample_image(name)
        except Exception as exc:  # a sample missing from this scikit-image build
            log.warning("skipping scikit-image sample %s: %s", name, exc)
            continue
        h, w = image.shape
        for view in range(views_per_image):
            scale = rng.uniform(0.6, 2.0) * max(out_w / w, out_h / h) ** 0.5
            angle = rng.uniform(-180, 180) if view else 0.0
            A = cv2.getRotationMatrix2D((w / 2, h / 2), angle, scale)
            A[:, 2] += (out_w / 2 - w / 2, out_h / 2 - h / 2)
            H = np.vstack([A, [0, 0, 1]])
            corners = np.float32([[0, 0], [out_w, 0], [out_w, out_h], [0, out_h]])
            jitter = rng.uniform(-0.12, 0.12, (4, 2)) * (out_w, out_h)
            P = cv2.getPerspectiveTransform(corners, (corners + jitter).astype(np.float32))
            warped = cv2.warpPerspective(image, P @ H, (out_w, out_h), flags=cv2.INTER_LINEAR,
                                         borderMode=cv2.BORDER_REFLECT)
            gamma = rng.uniform(0.7, 1.4)
            warped = (255.0 * (warped / 255.0) ** gamma).astype(np.uint8)
            if rng.uniform() < 0.3:
                warped = cv2.GaussianBlur(warped, (5, 5), 1.0)
            yield warped


def default_training_descriptors(views_per_image: int = 24, seed: int = 0, n_features: int = 1000
                                 ) -> list[np.ndarray]:
    """ORB descriptors of :func:`default_training_images`, one array per view."""
    return [extract_orb(img, n_features) for img in default_training_images(views_per_image, seed)]
