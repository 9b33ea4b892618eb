"""ORB description of given keypoints: intensity-centroid orientation (Rosin 1999; Rublee et al.,
ICCV 2011, eq. 1-3) and rotated BRIEF descriptors (compiled, :class:`RotatedBrief`), bit for bit those
of ``cv2.ORB.compute`` with ``nlevels=1``."""
from __future__ import annotations

import operator

import cv2
import numpy as np

from vslam.errors import VslamError
from vslam.features import orb_describe_kernels, orb_kernels
from vslam.features.keypoints import Features
from vslam.features.orb_pattern import PAIRS_31
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


def _opencv_random_pairs(patch_size: int) -> np.ndarray:
    """The pattern ``cv2.ORB`` uses when ``patchSize != 31``: 512 points drawn uniformly from
    ``[-r, r]^2`` (``r = patch_size // 2``, x then y) by OpenCV's multiply-with-carry generator
    (``state = lo32(state) * 4164903690 + hi32(state)``, output ``lo32(state)``) seeded 0x34985739,
    an integer ``u`` in ``[a, b)`` being ``a + u32 % (b - a)``; consecutive points form the pairs."""
    state = 0x34985739
    r = patch_size // 2
    pts = []
    for _ in range(2 * 512):
        state = ((state & 0xFFFFFFFF) * 4164903690 + (state >> 32)) & 0xFFFFFFFFFFFFFFFF
        pts.append(-r + (state & 0xFFFFFFFF) % (2 * r + 1))
    return np.array(pts, np.int64).reshape(256, 4)


class RotatedBrief:
    """Rotated BRIEF (ORB, Rublee et al. ICCV 2011 Sec. 4) of keypoints at given pixels and angles
    of one image, identical to ``cv2.ORB_create(nlevels=1, edgeThreshold=border,
    patchSize=patch_size).compute`` on ``cv2.KeyPoint`` s with the same ``pt`` and ``angle``
    (checked bit for bit in the tests), without making the keypoints.

    What OpenCV does, and so do we: drop the keypoints outside ``border <= x < W - border`` (same
    for ``y``; ``x`` rounded to the pixel), smooth the image by a 7 x 7, sigma 2 Gaussian (OpenCV
    blurs the image in place inside its padded buffer, which takes the float separable filter, not
    ``GaussianBlur``'s fixed-point one: ``cv2.sepFilter2D`` with the float32 Gaussian kernel and
    reflect-101 borders is that filter), then compare the smoothed intensities at the rotated
    pattern pairs, centred on the rounded keypoint (compiled:
    :func:`vslam.features.orb_describe_kernels.orb_descriptors`). Samples that leave the image
    read OpenCV's reflect-101 padding, unsmoothed, as OpenCV does; with the default border (19)
    and patch (31) none do."""

    def __init__(self, patch_size: int = 31, border: int = 19) -> None:
        pairs = PAIRS_31 if patch_size == 31 else _opencv_random_pairs(patch_size)
        self.pairs = np.asarray(pairs, np.int64)
        pts = self.pairs.reshape(-1, 2).astype(np.float32)  # points 2q, 2q + 1 form pair q
        self.px = np.ascontiguousarray(pts[:, 0])
        self.py = np.ascontiguousarray(pts[:, 1])
        self.border = int(border)
        # farthest rotated sample from the centre per axis after rounding (|x| <= norm, rounding is
        # monotone): 18 px for the 31 x 31 pattern
        self.reach = int(np.rint(np.sqrt((pairs.reshape(-1, 2).astype(np.float64) ** 2).sum(1)).max()))
        self.pad = max(0, self.reach - self.border)
        self.kernel = cv2.getGaussianKernel(7, 2.0, ktype=cv2.CV_32F)
        orb_describe_kernels.warm()

    def smooth(self, img: np.ndarray) -> np.ndarray:
        """The image the descriptors read: ``img`` smoothed, padded by ``self.pad`` pixels of its
        unsmoothed reflect-101 extension (no padding in the default configuration)."""
        blurred = cv2.sepFilter2D(img, cv2.CV_8U, self.kernel, self.kernel, borderType=cv2.BORDER_REFLECT_101)
        p = self.pad
        if p == 0:
            return blurred
        out = cv2.copyMakeBorder(img, p, p, p, p, cv2.BORDER_REFLECT_101)
        out[p:-p, p:-p] = blurred
        return out

    def inside(self, x: np.ndarray, y: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
        """``cv2.KeyPointsFilter.runByImageBorder``: which keypoints ``(x, y)`` (float32 or int)
        are, rounded to the pixel (half to even, as OpenCV's ``cvRound``), at least ``border`` from
        the edges of an image of ``shape = (H, W)``."""
        h, w = shape
        b = self.border
        x, y = np.asarray(x), np.asarray(y)
        if x.dtype.kind == "f":
            x, y = np.rint(x), np.rint(y)
        return (x >= b) & (y >= b) & (x < w - b) & (y < h - b)

    def describe(self, smoothed: np.ndarray, x: np.ndarray, y: np.ndarray, angle: np.ndarray) -> np.ndarray:
        """``(N, 32) uint8`` descriptors of keypoints centred on the integer pixels ``(x, y)`` of the
        original image (all ``inside`` it), ``angle`` in degrees; ``smoothed`` from :meth:`smooth`."""
        n = len(x)
        out = np.empty((n, self.pairs.shape[0] // 8), np.uint8)
        if n == 0:
            return out
        p = self.pad
        cx = np.ascontiguousarray(x, np.int64) + p
        cy = np.ascontiguousarray(y, np.int64) + p
        h, w = smoothed.shape
        r = self.reach
        if cx.min() < r or cy.min() < r or cx.max() >= w - r or cy.max() >= h - r:  # unchecked reads
            raise VslamError(f"ORB descriptor pattern of reach {r} leaves the {w}x{h} image")
        orb_describe_kernels.orb_descriptors(np.ascontiguousarray(smoothed), cx, cy,
                                             np.ascontiguousarray(angle, np.float32), self.px, self.py, out)
        return out


def responses(kps) -> np.ndarray:
    """``(N,) float32`` ``response`` of a keypoint list."""
    return np.fromiter(map(_RESPONSE, kps), np.float32, len(kps))


_RESPONSE = operator.attrgetter("response")



def describe_orb(gray: np.ndarray, uv: np.ndarray, brief: RotatedBrief | None = None,
                 orientation: Orientation | None = None, patch_size: int = 31,
                 scale_factor: float = 1.2) -> Features:
    """ORB descriptors (orientation by intensity centroid) at given level-0 pixels ``uv (N, 2)``.

    Points too close to the border for the descriptor pattern (rounded to the pixel they are
    described at) are dropped; the returned ``Features`` keep the input order of the survivors
    (check ``uv``)."""
    gray = check_gray(gray)
    uv = np.asarray(uv, np.float32).reshape(-1, 2)
    border = max(19, patch_size // 2 + 1)
    if brief is None:
        brief = RotatedBrief(patch_size, border)
    if orientation is None:
        orientation = Orientation(patch_size)
    h, w = gray.shape
    xi = np.round(uv[:, 0]).astype(np.int64)  # half to even, as OpenCV's cvRound
    yi = np.round(uv[:, 1]).astype(np.int64)
    ok = (xi >= border) & (yi >= border) & (xi < w - border) & (yi < h - border)
    if brief.border != border:
        ok &= brief.inside(xi, yi, gray.shape)
    sel = np.flatnonzero(ok)
    if len(sel) == 0:
        return Features.empty(True, 32, scale_factor)
    ang = orientation(gray, xi[sel], yi[sel])
    desc = brief.describe(brief.smooth(gray), xi[sel], yi[sel], ang)
    n = len(sel)
    return Features(uv[sel], desc, np.zeros(n, np.int32), np.zeros(n, np.float32),
                    ang, np.full(n, patch_size, np.float32), True, scale_factor)
