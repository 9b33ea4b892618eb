"""ORB description of given keypoints: intensity-centroid orientation (Rosin 1999; Rublee et al.,
ICCV 2011, eq. 1-3) and rotated BRIEF descriptors computed by OpenCV, with the bookkeeping of which
keypoints OpenCV kept."""
from __future__ import annotations

import itertools
import operator

import cv2
import numpy as np

from vslam.features.keypoints import Features
from vslam.features.pyramid import check_gray


class Orientation:
    """Intensity-centroid orientation (ORB eq. 1-3) on a circular patch of radius ``r``, for many
    keypoints at once. The disc is a stack of row segments ``[-umax(dy), umax(dy)]``, so with
    per-row prefix sums of ``I`` and ``x*I`` every moment is 2 lookups per row (exact, int64)."""

    def __init__(self, patch_size: int) -> None:
        r = patch_size // 2
        self.radius = r
        dy = np.arange(-r, r + 1)
        self.dy = dy.astype(np.int64)
        self.dyf = dy.astype(np.float64)
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
        self.umax = np.r_[half[: r + 1][::-1], half[1 : r + 1]]

    def __call__(self, img: np.ndarray, x: np.ndarray, y: np.ndarray, integral=None) -> np.ndarray:
        """Angles in degrees ``[0, 360)`` at integer pixel ``(x, y)`` of ``img`` (>= r from border).

        ``m01 = sum_dy dy * rowsum(dy)`` and, the disc being symmetric,
        ``m10 = sum_dx dx * colsum(dx)``; each segment sum is 4 lookups in the integral image."""
        if len(x) == 0:
            return np.zeros(0, np.float32)
        ii = integral if integral is not None else cv2.integral(img, sdepth=cv2.CV_32S)
        f = ii.reshape(-1)
        w1 = ii.shape[1]
        d, u = self.dy, self.umax
        # one flat base index per keypoint plus per-row constant offsets (row y+d, columns
        # [x-u, x+u] for m01; column x+d, rows [y-u, y+u] for m10; integral index is exclusive)
        k = (np.asarray(y, np.int64) * w1 + np.asarray(x, np.int64))[:, None]
        r0, r1 = d * w1, (d + 1) * w1
        rows = f[k + (r1 + u + 1)] - f[k + (r1 - u)] - f[k + (r0 + u + 1)] + f[k + (r0 - u)]
        t, btm = -u * w1, (u + 1) * w1
        cols = f[k + (btm + d + 1)] - f[k + (btm + d)] - f[k + (t + d + 1)] + f[k + (t + d)]
        # segment sums fit int32; the moments are integers far below 2^53: exact in float64
        m01 = rows.astype(np.float64) @ self.dyf
        m10 = cols.astype(np.float64) @ self.dyf
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
