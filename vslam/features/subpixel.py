"""Sub-pixel refinement of integer corners (issue #24 candidate, ``features.subpixel``).

``parabola`` (:func:`subpixel_peaks`): the peak of the Shi-Tomasi response (the smaller eigenvalue
of the 3x3-window structure tensor of central-difference gradients, Shi & Tomasi, CVPR 1994) on the
corner's 3x3 neighbourhood, interpolated by a parabola through the three values along each axis,
``dx = (R_-1 - R_+1) / (2 (R_-1 - 2 R_0 + R_+1))``, clipped to half a pixel; an axis along which the
response is not concave keeps the integer coordinate. One compiled pass per corner over its 7x7
patch (no response image is made).

``cornersubpix`` (:func:`subpixel_corners`): ``cv2.cornerSubPix`` (Foerstner & Guelch 1987), whose
shift is kept only within half a pixel (a FAST corner is not always a gradient-orthogonal corner).
"""
from __future__ import annotations

import cv2
import numpy as np
from numba import njit

_SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 10, 0.01)


@njit(cache=True, nogil=True)
def _peaks(img, x, y, xf, yf):  # pragma: no cover - compiled
    """``xf, yf`` (float64) = the parabola peak of the min-eigenvalue response around ``(x, y)``
    (corners at least 4 px inside ``img``)."""
    gx = np.empty((5, 5))
    gy = np.empty((5, 5))
    R = np.empty((3, 3))
    for k in range(x.shape[0]):
        x0 = x[k]
        y0 = y[k]
        for i in range(5):
            for j in range(5):
                r = y0 - 2 + i
                c = x0 - 2 + j
                gx[i, j] = 0.5 * (float(img[r, c + 1]) - float(img[r, c - 1]))
                gy[i, j] = 0.5 * (float(img[r + 1, c]) - float(img[r - 1, c]))
        for a in range(3):
            for b in range(3):
                sxx = 0.0
                syy = 0.0
                sxy = 0.0
                for i in range(a, a + 3):
                    for j in range(b, b + 3):
                        sxx += gx[i, j] * gx[i, j]
                        syy += gy[i, j] * gy[i, j]
                        sxy += gx[i, j] * gy[i, j]
                R[a, b] = 0.5 * (sxx + syy) - np.sqrt(0.25 * (sxx - syy) ** 2 + sxy * sxy)
        xf[k] = x0 + _offset(R[1, 0], R[1, 1], R[1, 2])
        yf[k] = y0 + _offset(R[0, 1], R[1, 1], R[2, 1])


@njit(cache=True, nogil=True)
def _offset(lo, mid, hi):  # pragma: no cover - compiled
    den = lo - 2.0 * mid + hi
    if not den < 0.0:
        return 0.0
    return min(0.5, max(-0.5, 0.5 * (lo - hi) / den))


def subpixel_peaks(img: np.ndarray, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sub-pixel ``(x, y)`` (float64, level pixels) of integer corners at least 4 px inside ``img``
    (uint8), by the parabola through the Shi-Tomasi response (module docstring).

    >>> img = cv2.GaussianBlur(np.kron([[20, 20], [20, 220]], np.ones((20, 20))).astype(np.uint8), (0, 0), 1.5)
    >>> xf, yf = subpixel_peaks(img, np.array([21]), np.array([21]))  # moves towards the corner
    >>> bool(xf[0] < 21 and yf[0] < 21)
    True
    """
    xf = np.empty(len(x))
    yf = np.empty(len(y))
    _peaks(np.ascontiguousarray(img), np.asarray(x, np.int64), np.asarray(y, np.int64), xf, yf)
    return xf, yf


def subpixel_corners(img: np.ndarray, x: np.ndarray, y: np.ndarray, half_window: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """Sub-pixel ``(x, y)`` (float64) of integer corners by ``cv2.cornerSubPix``; a refined location
    more than half a pixel from its corner keeps the integer one (module docstring)."""
    if len(x) == 0:
        return x.astype(np.float64), y.astype(np.float64)
    pts = np.stack([x, y], 1).astype(np.float32).reshape(-1, 1, 2)
    ref = cv2.cornerSubPix(img, pts.copy(), (half_window, half_window), (-1, -1), _SUBPIX_CRITERIA).reshape(-1, 2)
    keep = np.all(np.abs(ref - pts.reshape(-1, 2)) <= 0.5, axis=1)
    return np.where(keep, ref[:, 0], x).astype(np.float64), np.where(keep, ref[:, 1], y).astype(np.float64)
