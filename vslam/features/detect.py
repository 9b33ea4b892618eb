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

import logging
from typing import Protocol

import cv2
import numpy as np

from vslam.errors import ConfigError
from vslam.features import orb_kernels
from vslam.features.config import FeatureConfig
from vslam.features.keypoints import Features
from vslam.features.orb_describe import Orientation, RotatedBrief, describe_orb, responses
from vslam.features.pyramid import build_pyramid, check_gray, grid_select, level_quotas
from vslam.features.subpixel import subpixel_corners, subpixel_peaks

__all__ = [
    "Detector", "Features", "GfttOrbDetector", "OpenCVDetector", "OrbGridDetector", "build_pyramid",
    "create_detector", "describe_orb", "grid_select", "level_quotas",
]

log = logging.getLogger(__name__)


class Detector(Protocol):
    """What :func:`create_detector` returns."""

    config: FeatureConfig

    def detect(self, gray: np.ndarray, mask: np.ndarray | None = None) -> Features: ...


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

    Descriptors are computed per level on our own pyramid images by :class:`RotatedBrief`, bit for
    bit those of an ``nlevels=1`` ``cv2.ORB`` (each level blurred by the same 7x7, sigma 2 Gaussian
    as multi-level ORB does), without a list of ``cv2.KeyPoint`` or OpenCV's pyramid buffer."""

    def __init__(self, config: FeatureConfig) -> None:
        self.config = config
        c = config
        self.quotas = level_quotas(c.n_features, c.n_levels, c.scale_factor)
        self.fast = cv2.FastFeatureDetector_create(threshold=c.fast_threshold, nonmaxSuppression=True)
        self.fast_low = None
        if 0 < c.min_fast_threshold < c.fast_threshold:
            self.fast_low = cv2.FastFeatureDetector_create(threshold=c.min_fast_threshold, nonmaxSuppression=True)
        self.border = max(c.edge_threshold, c.patch_size // 2 + 1)
        self.brief = RotatedBrief(c.patch_size, self.border)
        self.orientation = Orientation(c.patch_size)

    def _fast(self, detector, img: np.ndarray, mask: np.ndarray | None):
        """FAST corners inside the descriptor border: integer ``x, y`` and the FAST score.

        FAST runs on the crop 4 px beyond that border only: a corner's score depends on its
        7 x 7 neighbourhood and its suppression on its 8 neighbours' scores, all inside the crop
        for every corner kept, so the result is the whole image's (fewer pixels and keypoints)."""
        h, w = img.shape
        b = self.border
        o = max(b - 4, 0)
        crop = img[o : h - o, o : w - o]
        kps = detector.detect(crop, None if mask is None else mask[o : h - o, o : w - o])
        if not kps:
            z = np.zeros(0, np.int64)
            return z, z.copy(), np.zeros(0, np.float32)
        pts = cv2.KeyPoint_convert(kps)
        score = responses(kps)
        x = pts[:, 0].astype(np.int64) + o
        y = pts[:, 1].astype(np.int64) + o
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
            ss.append(responses(kps))
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
            # FAST scores are integers 0..255 and x, y >= 0: grid_select's counting-sort path, called
            # directly (x // cs equals its float32 floor division for pixel coordinates)
            keep = orb_kernels.grid_order(x // cs, y // cs, score.astype(np.int64), int(quotas[lvl]))
            if lvl + 1 < len(quotas):  # unused quota moves up the pyramid
                quotas[lvl + 1] += max(0, int(quotas[lvl]) - len(keep))
            out.append((x[keep], y[keep], score[keep]))
        return out

    def _subpixel(self, img: np.ndarray, x: np.ndarray, y: np.ndarray, lvl: int) -> tuple[np.ndarray, np.ndarray]:
        """Level-``lvl`` corner positions: the integer FAST ones, or refined (``features.subpixel``)."""
        c = self.config
        if c.subpixel in ("off", "auto") or not c.subpixel_min_octave <= lvl <= c.subpixel_max_octave:
            return x, y
        if c.subpixel == "cornersubpix":
            return subpixel_corners(img, x, y, c.subpixel_window)
        return subpixel_peaks(img, x, y)

    def detect(self, gray: np.ndarray, mask: np.ndarray | None = None) -> Features:
        c = self.config
        gray = check_gray(gray)
        h0, w0 = gray.shape
        levels = build_pyramid(gray, c.n_levels, c.scale_factor)
        parts = []
        for lvl, cand in enumerate(self.candidates(levels, mask)):
            if cand is None or len(cand[0]) == 0:
                continue
            x, y, score = cand
            img = levels[lvl]
            hl, wl = img.shape
            inside = self.brief.inside(x, y, img.shape)  # all of them: FAST ran inside this border
            if not inside.all():
                x, y, score = x[inside], y[inside], score[inside]
            ang = self.orientation(img, x, y)
            desc = self.brief.describe(self.brief.smooth(img), x, y, ang)
            xf, yf = self._subpixel(img, x, y, lvl)
            # pixel-centre-correct level-0 position: x0 = (x + 0.5) * W / W_l - 0.5 (a bias of
            # up to (s - 1) / 2 px otherwise, which does not cancel under rotation or zoom)
            uv = np.stack([(xf + 0.5) * (w0 / wl) - 0.5, (yf + 0.5) * (h0 / hl) - 0.5], 1)
            parts.append((uv, desc, np.full(len(x), lvl, np.int32), score, ang))
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
        self.brief = RotatedBrief(c.patch_size, self.border)
        self.orientation = Orientation(c.patch_size)

    def detect(self, gray: np.ndarray, mask: np.ndarray | None = None) -> Features:
        c = self.config
        gray = check_gray(gray)
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
        return describe_orb(gray, uv, self.brief, self.orientation, c.patch_size, c.scale_factor)



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
        gray = check_gray(gray)
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
