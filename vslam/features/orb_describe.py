"""ORB description of given keypoints: intensity-centroid orientation (Rosin 1999; Rublee et al.,
ICCV 2011, eq. 1-3) and rotated BRIEF descriptors computed by OpenCV, with the bookkeeping of which
keypoints OpenCV kept."""
from __future__ import annotations

import itertools
import operator

import cv2
import numpy as np

from vslam.errors import VslamError
from vslam.features import orb_kernels
from vslam.features.keypoints import Features
from vslam.features.pyramid import check_gray


class Orientation:
    """Intensity-centroid orientation (ORB eq. 1-3) on a circular patch of radius ``r``, for many
    keypoints at once. The disc is a stack of row segments ``[-umax(dy), umax(dy)]``; the moments
    are exact integer sums over it (one compiled pass per keypoint)."""

    def __init__(self, patch_size: int) -> None:
        r = patch_size // 2
        self.radius = r
        # Half-widths of the disc rows, made symmetric in u and v like OpenCV's ORB, so the angles
        # agree with cv2.ORB to ~0.01 degree (checked in the tests).
        half = np.zeros(r + 2, np.int64)
        vmax = int(np.floor(r * np.sqrt(2.0) / 2 + 1))
        vmin = int(np.ceil(r * np.sqrt(2.0) / 2))
        half[: vmax + 1] = np.round(np.sqrt(r * r - np.arange(vmax + 1) ** 2.0)).astype(np.int64)
        v0 = 0
        for v in range(r, vmin - 1, -1):
            while half[v0] == half[v0 + 1]:
                v0 += 1
            half[v] = v0
            v0 += 1
        self.umax = np.ascontiguousarray(np.r_[half[: r + 1][::-1], half[1 : r + 1]], np.int64)
        # the disc {|dx| <= umax[dy]} equals its transpose, so one pass over its rows gives both moments
        disc = np.abs(np.arange(-r, r + 1))[None, :] <= self.umax[:, None]
        assert (disc == disc.T).all(), "ORB orientation disc must be symmetric"
        orb_kernels.warm()

    def __call__(self, img: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Angles in degrees ``[0, 360)`` at integer pixel ``(x, y)`` of ``img`` (>= r from border).

        ``m01 = sum_dy dy * rowsum(dy)`` and ``m10 = sum_dx dx * colsum(dx)`` over the disc, exact
        integers (compiled: :func:`vslam.features.orb_kernels.ic_moments`), then ``atan2``."""
        if len(x) == 0:
            return np.zeros(0, np.float32)
        n = len(x)
        x = np.ascontiguousarray(x, np.int64)
        y = np.ascontiguousarray(y, np.int64)
        h, w = img.shape
        r = self.radius
        if x.min() < r or y.min() < r or x.max() >= w - r or y.max() >= h - r:  # the kernel reads unchecked
            raise VslamError(f"orientation patch of radius {r} leaves the {w}x{h} image")
        m01 = np.empty(n, np.float64)
        m10 = np.empty(n, np.float64)
        orb_kernels.ic_moments(np.ascontiguousarray(img), x, y, self.umax, m01, m10)
        ang = np.degrees(np.arctan2(m01, m10))
        return np.mod(ang, 360.0).astype(np.float32)


def make_keypoints(x: np.ndarray, y: np.ndarray, angle: np.ndarray, size: float) -> list:
    """``cv2.KeyPoint`` list at ``(x, y)`` with ``angle`` (degrees), octave 0 (built by ``map`` over
    the 4-argument constructor, the fastest way to make many of them from Python)."""
    n = len(x)
    return list(map(cv2.KeyPoint, np.asarray(x, np.float64).tolist(), np.asarray(y, np.float64).tolist(),
                    itertools.repeat(size, n), np.asarray(angle, np.float64).tolist()))


def survivors(kps_out: list, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Input indices of the keypoints ``cv2.ORB.compute`` kept from those made at ``(x, y)``. ORB
    only drops points (border filter, order-preserving), so when none were dropped they are
    ``arange(len(x))``; otherwise one walk along both lists matches the (float32) positions."""
    n_in = len(x)
    if len(kps_out) == n_in:
        return np.arange(n_in, dtype=np.int64)
    pts = cv2.KeyPoint_convert(kps_out).reshape(-1, 2).tolist()
    xin = np.asarray(x, np.float32).tolist()
    yin = np.asarray(y, np.float32).tolist()
    out = np.empty(len(pts), np.int64)
    j = 0
    for i, (u, v) in enumerate(pts):  # rare path (points dropped by OpenCV)
        while xin[j] != u or yin[j] != v:
            j += 1
        out[i] = j
        j += 1
    return out


def responses(kps) -> np.ndarray:
    """``(N,) float32`` ``response`` of a keypoint list."""
    return np.fromiter(map(_RESPONSE, kps), np.float32, len(kps))


_RESPONSE = operator.attrgetter("response")



def describe_orb(gray: np.ndarray, uv: np.ndarray, orb=None, orientation: Orientation | None = None,
                 patch_size: int = 31, scale_factor: float = 1.2) -> Features:
    """ORB descriptors (orientation by intensity centroid) at given level-0 pixels ``uv (N, 2)``.

    Points too close to the border for the descriptor pattern are dropped; the returned
    ``Features`` keep the input order of the survivors (check ``uv``)."""
    gray = check_gray(gray)
    uv = np.asarray(uv, np.float32).reshape(-1, 2)
    border = max(19, patch_size // 2 + 1)
    if orb is None:
        orb = cv2.ORB_create(nfeatures=max(1, len(uv)), nlevels=1, edgeThreshold=border, patchSize=patch_size)
    if orientation is None:
        orientation = Orientation(patch_size)
    h, w = gray.shape
    xi = np.round(uv[:, 0]).astype(np.int64)
    yi = np.round(uv[:, 1]).astype(np.int64)
    ok = (xi >= border) & (yi >= border) & (xi < w - border) & (yi < h - border)
    idx_ok = np.flatnonzero(ok)
    if len(idx_ok) == 0:
        return Features.empty(True, 32, scale_factor)
    ang = orientation(gray, xi[ok], yi[ok])
    kps = make_keypoints(uv[ok, 0], uv[ok, 1], ang, float(patch_size))
    kps_out, desc = orb.compute(gray, kps)
    if desc is None or not kps_out:
        return Features.empty(True, 32, scale_factor)
    ids = survivors(kps_out, uv[ok, 0], uv[ok, 1])
    order = np.argsort(ids, kind="stable")
    ids, desc = ids[order], desc[order]
    sel = idx_ok[ids]
    n = len(sel)
    return Features(uv[sel], np.ascontiguousarray(desc), np.zeros(n, np.int32), np.zeros(n, np.float32),
                    ang[ids], np.full(n, patch_size, np.float32), True, scale_factor)
