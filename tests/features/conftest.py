"""Fixtures for the feature-layer tests: scikit-image textures and exactly known warps."""
from __future__ import annotations

import cv2
import numpy as np
import pytest
import skimage.data


def _gray(name: str) -> np.ndarray:
    img = getattr(skimage.data, name)()
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
    return np.ascontiguousarray(img)


@pytest.fixture(scope="session")
def brick() -> np.ndarray:
    """512x512 brick-wall texture (uint8)."""
    return _gray("brick")


@pytest.fixture(scope="session")
def gravel() -> np.ndarray:
    """512x512 gravel texture: well-conditioned corners everywhere (uint8)."""
    return _gray("gravel")


@pytest.fixture(scope="session")
def astronaut() -> np.ndarray:
    """512x512 natural image (uint8 grayscale)."""
    return _gray("astronaut")


def fourier_shift_image(img: np.ndarray, du: float, dv: float) -> np.ndarray:
    """``img`` moved by ``(du, dv)`` pixels (sub-pixel exact for band-limited content; periodic)."""
    from scipy.ndimage import fourier_shift

    out = np.fft.ifftn(fourier_shift(np.fft.fftn(img.astype(np.float64)), (dv, du))).real
    return np.clip(np.round(out), 0, 255).astype(np.uint8)


@pytest.fixture(scope="session")
def shift_image():
    return fourier_shift_image


@pytest.fixture(scope="session")
def warp_homography():
    """A mild perspective warp (8 deg rotation, 1.03 scale, small perspective) and the warped image."""

    def make(img: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        h, w = img.shape
        c = np.array([[1, 0, -w / 2], [0, 1, -h / 2], [0, 0, 1.0]])
        a = np.deg2rad(8.0)
        S = np.array([[1.03 * np.cos(a), -1.03 * np.sin(a), 0], [1.03 * np.sin(a), 1.03 * np.cos(a), 0],
                      [1e-4, -5e-5, 1.0]])
        H = np.linalg.inv(c) @ S @ c
        warped = cv2.warpPerspective(img, H, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
        return H, warped

    return make


def apply_h(H: np.ndarray, uv: np.ndarray) -> np.ndarray:
    p = np.c_[uv, np.ones(len(uv))] @ H.T
    return p[:, :2] / p[:, 2:]


@pytest.fixture(scope="session")
def homography_apply():
    return apply_h
