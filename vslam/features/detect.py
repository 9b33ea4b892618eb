"""Feature detection and description: grid-distributed ORB over a scale pyramid, SIFT, AKAZE, BRISK,
and Shi-Tomasi corners with ORB descriptors.

ORB here follows Rublee et al., "ORB: an efficient alternative to SIFT or SURF" (ICCV 2011) and
ORB-SLAM's distribution (Mur-Artal et al., T-RO 2015, Sec. III-B): FAST corners on every level of a
pyramid, a per-level quota proportional to ``scale_factor^-level``, candidates spread over a grid
(best FAST score of every cell first, then second best, ...), orientation by the intensity
centroid (Rosin 1999, ORB eq. 1-3: ``theta = atan2(m01, m10)`` over a circular patch), then rotated
BRIEF descriptors computed once by OpenCV for the kept keypoints.

Example:
    >>> det = create_detector(FeatureConfig(n_features=1000))        # doctest: +SKIP
    >>> feats = det.detect(gray)                                      # doctest: +SKIP
    >>> feats.uv.shape, feats.descriptors.shape                       # doctest: +SKIP
    ((1000, 2), (1000, 32))
"""
from __future__ import annotations

import itertools
import logging
import operator
from dataclasses import dataclass
from typing import Protocol

import cv2
import numpy as np

from vslam.errors import ConfigError, VslamError
from vslam.features.config import FeatureConfig

log = logging.getLogger(__name__)


@dataclass
class Features:
    """Keypoints and descriptors of one image.

    Attributes:
        uv: ``(N, 2) float32`` pixel coordinates at level 0, as detected (in the possibly
            distorted image).
        descriptors: ``(N, D)``; ``uint8`` packed bits for binary descriptors, ``float32`` otherwise.
        octave: ``(N,) int32`` pyramid level (0 = full resolution).
        response: ``(N,) float32`` detector score.
        angle: ``(N,) float32`` orientation in degrees ``[0, 360)`` (or -1 when not defined).
        size: ``(N,) float32`` keypoint diameter in level-0 pixels.
        binary: True for Hamming descriptors, False for L2.
        scale_factor: pyramid scale between levels; level ``l`` has scale ``scale_factor**l``,
            so the measurement sigma of a keypoint is ``scale_factor**octave`` pixels.
    """

    uv: np.ndarray
    descriptors: np.ndarray
    octave: np.ndarray
    response: np.ndarray
    angle: np.ndarray
    size: np.ndarray
    binary: bool
    scale_factor: float = 1.2

    def __len__(self) -> int:
        return int(self.uv.shape[0])

    @property
    def scales(self) -> np.ndarray:
        """``(N,)`` scale of each keypoint's level, ``scale_factor ** octave``."""
        return np.power(float(self.scale_factor), self.octave.astype(np.float64))

    def subset(self, idx: np.ndarray) -> "Features":
        """The features at ``idx`` (indices or boolean mask), same metadata."""
        return Features(
            self.uv[idx], self.descriptors[idx], self.octave[idx], self.response[idx],
            self.angle[idx], self.size[idx], self.binary, self.scale_factor,
        )

    @staticmethod
    def empty(binary: bool = True, dim: int = 32, scale_factor: float = 1.2) -> "Features":
        dt = np.uint8 if binary else np.float32
        z = np.zeros(0, np.float32)
        return Features(np.zeros((0, 2), np.float32), np.zeros((0, dim), dt), np.zeros(0, np.int32),
                        z, z.copy(), z.copy(), binary, scale_factor)


class Detector(Protocol):
    """What :func:`create_detector` returns."""

    config: FeatureConfig

    def detect(self, gray: np.ndarray, mask: np.ndarray | None = None) -> Features: ...


def _check_gray(gray: np.ndarray) -> np.ndarray:
    gray = np.asarray(gray)
    if gray.ndim == 3 and gray.shape[2] == 3:
        gray = cv2.cvtColor(gray, cv2.COLOR_BGR2GRAY)
    if gray.ndim != 2:
        raise VslamError(f"feature detection needs a (H, W) grayscale image, got shape {gray.shape}")
    if gray.dtype != np.uint8:
        raise VslamError(f"feature detection needs a uint8 image, got dtype {gray.dtype}")
    return np.ascontiguousarray(gray)


def build_pyramid(gray: np.ndarray, n_levels: int, scale_factor: float) -> list[np.ndarray]:
    """Image pyramid as OpenCV's ORB builds it: level ``l`` is ``round(W / s^l) x round(H / s^l)``,
    each resized (bilinear, ``INTER_LINEAR_EXACT``) from the previous level."""
    levels = [gray]
    h, w = gray.shape
    for lvl in range(1, n_levels):
        s = scale_factor**lvl
        size = (int(round(w / s)), int(round(h / s)))
        if min(size) < 8:
            break
        levels.append(cv2.resize(levels[-1], size, interpolation=cv2.INTER_LINEAR_EXACT))
    return levels


def level_quotas(n_features: int, n_levels: int, scale_factor: float) -> np.ndarray:
    """Features per level, a geometric series with ratio ``1/scale_factor`` summing to ``n_features``
    (ORB-SLAM's ``ORBextractor`` constructor)."""
    f = 1.0 / scale_factor
    per = n_features * (1 - f) / (1 - f**n_levels) * f ** np.arange(n_levels)
    q = np.floor(per).astype(np.int64)
    q[0] += n_features - q.sum()
    return q


def grid_select(uv: np.ndarray, score: np.ndarray, cell_size: float, n_keep: int) -> np.ndarray:
    """Indices of at most ``n_keep`` points spread over a grid of ``cell_size`` cells: the best
    point (highest ``score``) of every cell first, then the second best of every cell, and so on;
    inside a round, higher scores first (ties: lower index).

    Vectorized with two sorts of unique int64 keys (so an unstable quicksort is deterministic)."""
    n = len(uv)
    score = np.asarray(score)
    idx = np.arange(n, dtype=np.int64)
    # unique "badness" key, 0 for the best point: (score rank, index)
    if n and np.all(score == np.round(score)) and score.min() >= 0 and score.max() < 2**16:
        srank = (int(score.max()) - score).astype(np.int64) * n + idx  # FAST scores: small ints
    else:
        srank = np.empty(n, np.int64)
        srank[np.argsort(-score, kind="stable")] = idx
    if n <= n_keep:
        return np.argsort(srank)
    span = int(srank.max()) + 1
    cx = (uv[:, 0] // cell_size).astype(np.int64)
    cy = (uv[:, 1] // cell_size).astype(np.int64)
    cell = cy * (int(cx.max()) + 1) + cx
    order = np.argsort(cell * span + srank)  # by cell, then best first
    cs = cell[order]
    start = np.r_[True, cs[1:] != cs[:-1]]
    first = np.maximum.accumulate(np.where(start, idx, 0))
    rank = np.empty(n, np.int64)
    rank[order] = idx - first
    key = rank * span + srank  # unique: the n_keep smallest, in key order
    part = np.argpartition(key, n_keep - 1)[:n_keep] if n_keep > 0 else np.zeros(0, np.int64)
    return part[np.argsort(key[part])]


class _Orientation:
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


def _keypoints(x: np.ndarray, y: np.ndarray, angle: np.ndarray, size: float) -> list:
    """``cv2.KeyPoint`` list at ``(x, y)`` with ``angle`` (degrees), octave 0 (built by ``map`` over
    the 4-argument constructor, the fastest way to make many of them from Python)."""
    n = len(x)
    return list(map(cv2.KeyPoint, np.asarray(x, np.float64).tolist(), np.asarray(y, np.float64).tolist(),
                    itertools.repeat(size, n), np.asarray(angle, np.float64).tolist()))


def _survivors(kps_out: list, x: np.ndarray, y: np.ndarray) -> np.ndarray:
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


def _responses(kps) -> np.ndarray:
    """``(N,) float32`` ``response`` of a keypoint list."""
    return np.fromiter(map(_RESPONSE, kps), np.float32, len(kps))


_RESPONSE = operator.attrgetter("response")


def _features_from_keypoints(kps, desc, binary: bool, scale_factor: float, dim: int,
                             octave_decode=None) -> Features:
    if not kps or desc is None or len(desc) == 0:
        return Features.empty(binary, dim, scale_factor)
    uv = cv2.KeyPoint_convert(kps).astype(np.float32).reshape(-1, 2)
    octave = np.array([k.octave for k in kps], np.int64)
    if octave_decode is not None:
        octave = octave_decode(octave)
    return Features(
        uv=uv,
        descriptors=np.ascontiguousarray(desc, dtype=np.uint8 if binary else np.float32),
        octave=octave.astype(np.int32),
        response=np.array([k.response for k in kps], np.float32),
        angle=np.array([k.angle for k in kps], np.float32),
        size=np.array([k.size for k in kps], np.float32),
        binary=binary,
        scale_factor=scale_factor,
    )


class OrbGridDetector:
    """ORB with features spread over a grid on every pyramid level (see the module docstring).

    Descriptors are computed per level by an ``nlevels=1`` OpenCV ORB on our own pyramid
    images (OpenCV blurs each level with the same 7x7, sigma 2 Gaussian as multi-level ORB does),
    which skips OpenCV rebuilding the pyramid."""

    def __init__(self, config: FeatureConfig) -> None:
        self.config = config
        c = config
        self.quotas = level_quotas(c.n_features, c.n_levels, c.scale_factor)
        self.fast = cv2.FastFeatureDetector_create(threshold=c.fast_threshold, nonmaxSuppression=True)
        self.fast_low = None
        if 0 < c.min_fast_threshold < c.fast_threshold:
            self.fast_low = cv2.FastFeatureDetector_create(threshold=c.min_fast_threshold, nonmaxSuppression=True)
        self.border = max(c.edge_threshold, c.patch_size // 2 + 1)
        self.orb = cv2.ORB_create(nfeatures=c.n_features, nlevels=1, edgeThreshold=self.border,
                                  patchSize=c.patch_size)
        self.orientation = _Orientation(c.patch_size)

    def _fast(self, detector, img: np.ndarray, mask: np.ndarray | None):
        """FAST corners inside the descriptor border: integer ``x, y`` and the FAST score."""
        kps = detector.detect(img, mask)
        if not kps:
            z = np.zeros(0, np.int64)
            return z, z.copy(), np.zeros(0, np.float32)
        pts = cv2.KeyPoint_convert(kps)
        score = _responses(kps)
        x = pts[:, 0].astype(np.int64)
        y = pts[:, 1].astype(np.int64)
        h, w = img.shape
        b = self.border
        inside = (x >= b) & (y >= b) & (x < w - b) & (y < h - b)
        return x[inside], y[inside], score[inside]

    def _fast_in_cells(self, img: np.ndarray, empty: np.ndarray, mask: np.ndarray | None):
        """Low-threshold FAST only inside the ``empty`` grid cells ``(ny, nx)``: one call per
        grid row that has empty cells, on the crop from its first to its last empty cell padded
        by FAST's 3 px radius (OpenCV's mask argument would still scan the whole image)."""
        cs = self.config.cell_size
        h, w = img.shape
        xs, ys, ss = [], [], []
        pad = 3
        rows = np.flatnonzero(empty.any(axis=1))
        for r in rows.tolist():
            cols = np.flatnonzero(empty[r])
            y0, y1 = r * cs, min((r + 1) * cs, h)
            x0, x1 = int(cols[0]) * cs, min((int(cols[-1]) + 1) * cs, w)
            Y0, Y1, X0, X1 = max(y0 - pad, 0), min(y1 + pad, h), max(x0 - pad, 0), min(x1 + pad, w)
            kps = self.fast_low.detect(img[Y0:Y1, X0:X1], None if mask is None else mask[Y0:Y1, X0:X1])
            if not kps:
                continue
            pts = cv2.KeyPoint_convert(kps)
            xs.append(pts[:, 0].astype(np.int64) + X0)
            ys.append(pts[:, 1].astype(np.int64) + Y0)
            ss.append(_responses(kps))
        if not xs:
            z = np.zeros(0, np.int64)
            return z, z.copy(), np.zeros(0, np.float32)
        x, y, sc = np.concatenate(xs), np.concatenate(ys), np.concatenate(ss)
        b = self.border
        inside = (x >= b) & (y >= b) & (x < w - b) & (y < h - b)
        x, y, sc = x[inside], y[inside], sc[inside]
        keep = empty[y // cs, x // cs]  # only corners of the empty cells
        return x[keep], y[keep], sc[keep]

    def candidates(self, levels: list[np.ndarray], mask: np.ndarray | None):
        """Grid-selected FAST corners per level: ``(x, y, score)`` integer level coordinates.

        Two thresholds as in ORB-SLAM: FAST at ``fast_threshold`` everywhere, then at
        ``min_fast_threshold`` only in the grid cells left empty (a mask, so OpenCV returns only
        those corners: the cost of FAST here is mostly per returned corner)."""
        c = self.config
        cs = c.cell_size
        out = []
        quotas = self.quotas.copy()
        for lvl, img in enumerate(levels):
            if lvl >= len(quotas):
                break
            h, w = img.shape
            lvl_mask = None
            if mask is not None:
                lvl_mask = mask if lvl == 0 else cv2.resize(mask, (w, h), interpolation=cv2.INTER_NEAREST)
            x, y, score = self._fast(self.fast, img, lvl_mask)
            if self.fast_low is not None:
                ny, nx = -(-h // cs), -(-w // cs)
                occupied = np.zeros((ny, nx), np.uint8)
                occupied[y // cs, x // cs] = 1
                # cells fully outside the descriptor border can never hold a corner: not "empty"
                b = self.border
                occupied[: b // cs, :] = 1
                occupied[:, : b // cs] = 1
                occupied[(h - b) // cs + 1 :, :] = 1
                occupied[:, (w - b) // cs + 1 :] = 1
                if not occupied.all():
                    x2, y2, s2 = self._fast_in_cells(img, occupied == 0, lvl_mask)
                    x, y, score = np.r_[x, x2], np.r_[y, y2], np.r_[score, s2]
            if len(x) == 0:
                out.append(None)
                continue
            keep = grid_select(np.stack([x, y], 1).astype(np.float32), score, cs, int(quotas[lvl]))
            if lvl + 1 < len(quotas):  # unused quota moves up the pyramid
                quotas[lvl + 1] += max(0, int(quotas[lvl]) - len(keep))
            out.append((x[keep], y[keep], score[keep]))
        return out

    def detect(self, gray: np.ndarray, mask: np.ndarray | None = None) -> Features:
        c = self.config
        gray = _check_gray(gray)
        h0, w0 = gray.shape
        levels = build_pyramid(gray, c.n_levels, c.scale_factor)
        parts = []
        for lvl, cand in enumerate(self.candidates(levels, mask)):
            if cand is None or len(cand[0]) == 0:
                continue
            x, y, score = cand
            ang = self.orientation(levels[lvl], x, y)
            kps = _keypoints(x, y, ang, float(c.patch_size))
            kps_out, desc = self.orb.compute(levels[lvl], kps)
            if desc is None or not kps_out:
                continue
            ids = _survivors(kps_out, x, y)
            hl, wl = levels[lvl].shape
            # pixel-centre-correct level-0 position: x0 = (x + 0.5) * W / W_l - 0.5 (a bias of
            # up to (s - 1) / 2 px otherwise, which does not cancel under rotation or zoom)
            uv = np.stack([(x[ids] + 0.5) * (w0 / wl) - 0.5, (y[ids] + 0.5) * (h0 / hl) - 0.5], 1)
            parts.append((uv, desc, np.full(len(ids), lvl, np.int32), score[ids], ang[ids]))
        if not parts:
            return Features.empty(True, 32, c.scale_factor)
        uv, desc, octv, resp, ang = (np.concatenate(z) for z in zip(*parts))
        size = (c.patch_size * np.power(c.scale_factor, octv)).astype(np.float32)
        return Features(uv.astype(np.float32), np.ascontiguousarray(desc, np.uint8), octv,
                        resp.astype(np.float32), ang.astype(np.float32), size, True, c.scale_factor)


class GfttOrbDetector:
    """Shi-Tomasi corners (Shi & Tomasi, CVPR 1994) at full resolution with ORB descriptors: the
    corners KLT tracks best, still matchable against the map. All keypoints are on octave 0."""

    def __init__(self, config: FeatureConfig) -> None:
        self.config = config
        c = config
        self.border = max(c.edge_threshold, c.patch_size // 2 + 1)
        self.orb = cv2.ORB_create(nfeatures=c.n_features, scaleFactor=c.scale_factor, nlevels=1,
                                  edgeThreshold=self.border, patchSize=c.patch_size)
        self.orientation = _Orientation(c.patch_size)

    def detect(self, gray: np.ndarray, mask: np.ndarray | None = None) -> Features:
        c = self.config
        gray = _check_gray(gray)
        h, w = gray.shape
        b = self.border
        m = np.zeros((h, w), np.uint8)
        m[b : h - b, b : w - b] = 255
        if mask is not None:
            m &= np.asarray(mask, np.uint8)
        corners = cv2.goodFeaturesToTrack(gray, maxCorners=c.n_features, qualityLevel=c.gftt_quality,
                                          minDistance=c.gftt_min_distance, mask=m, blockSize=3)
        if corners is None:
            return Features.empty(True, 32, c.scale_factor)
        uv = corners.reshape(-1, 2).astype(np.float32)
        return describe_orb(gray, uv, self.orb, self.orientation, c.patch_size, c.scale_factor)


def describe_orb(gray: np.ndarray, uv: np.ndarray, orb=None, orientation: _Orientation | None = None,
                 patch_size: int = 31, scale_factor: float = 1.2) -> Features:
    """ORB descriptors (orientation by intensity centroid) at given level-0 pixels ``uv (N, 2)``.

    Points too close to the border for the descriptor pattern are dropped; the returned
    ``Features`` keep the input order of the survivors (check ``uv``)."""
    gray = _check_gray(gray)
    uv = np.asarray(uv, np.float32).reshape(-1, 2)
    border = max(19, patch_size // 2 + 1)
    if orb is None:
        orb = cv2.ORB_create(nfeatures=max(1, len(uv)), nlevels=1, edgeThreshold=border, patchSize=patch_size)
    if orientation is None:
        orientation = _Orientation(patch_size)
    h, w = gray.shape
    xi = np.round(uv[:, 0]).astype(np.int64)
    yi = np.round(uv[:, 1]).astype(np.int64)
    ok = (xi >= border) & (yi >= border) & (xi < w - border) & (yi < h - border)
    idx_ok = np.flatnonzero(ok)
    if len(idx_ok) == 0:
        return Features.empty(True, 32, scale_factor)
    ang = orientation(gray, xi[ok], yi[ok])
    kps = _keypoints(uv[ok, 0], uv[ok, 1], ang, float(patch_size))
    kps_out, desc = orb.compute(gray, kps)
    if desc is None or not kps_out:
        return Features.empty(True, 32, scale_factor)
    ids = _survivors(kps_out, uv[ok, 0], uv[ok, 1])
    order = np.argsort(ids, kind="stable")
    ids, desc = ids[order], desc[order]
    sel = idx_ok[ids]
    n = len(sel)
    return Features(uv[sel], np.ascontiguousarray(desc), np.zeros(n, np.int32), np.zeros(n, np.float32),
                    ang[ids], np.full(n, patch_size, np.float32), True, scale_factor)


class OpenCVDetector:
    """SIFT (Lowe, IJCV 2004), AKAZE (Alcantarilla et al., BMVC 2013) or BRISK (Leutenegger et al.,
    ICCV 2011) through OpenCV, keeping the ``n_features`` strongest responses."""

    def __init__(self, config: FeatureConfig) -> None:
        self.config = config
        c = config
        name = c.detector
        if name == "sift":
            self.impl = cv2.SIFT_create(nfeatures=c.n_features, contrastThreshold=c.sift_contrast_threshold)
            self.binary = False
            # OpenCV packs SIFT's octave in the low byte (signed; -1 = the upsampled first octave);
            # we shift it to start at 0, so scale_factor**octave over-estimates level 0's sigma.
            self.decode = lambda o: ((o & 255).astype(np.int64) ^ 0x80) - 0x80 + 1
            self.scale_factor = 2.0
        elif name == "akaze":
            self.impl = cv2.AKAZE_create(threshold=c.akaze_threshold)
            self.binary = True
            self.decode = None
            self.scale_factor = 2.0
        elif name == "brisk":
            self.impl = cv2.BRISK_create(thresh=c.brisk_threshold)
            self.binary = True
            self.decode = None
            self.scale_factor = 2.0
        else:  # pragma: no cover - guarded by create_detector
            raise ConfigError(f"OpenCVDetector does not handle detector={name!r}")

    def detect(self, gray: np.ndarray, mask: np.ndarray | None = None) -> Features:
        gray = _check_gray(gray)
        kps = self.impl.detect(gray, mask)
        if len(kps) > self.config.n_features:
            resp = np.array([k.response for k in kps], np.float32)
            keep = np.argsort(-resp, kind="stable")[: self.config.n_features]
            kps = [kps[i] for i in keep]
        kps, desc = self.impl.compute(gray, kps)
        return _features_from_keypoints(kps, desc, self.binary, self.scale_factor,
                                        self.impl.descriptorSize(), self.decode)


def create_detector(config: FeatureConfig | None = None) -> Detector:
    """A detector object for ``config.detector`` (create it once, call ``detect`` per frame)."""
    config = config or FeatureConfig()
    if config.detector == "orb":
        return OrbGridDetector(config)
    if config.detector == "gftt_orb":
        return GfttOrbDetector(config)
    if config.detector in ("sift", "akaze", "brisk"):
        return OpenCVDetector(config)
    raise ConfigError(f"features.detector={config.detector!r} is unknown")
