"""KLT tracking: pyramidal Lucas-Kanade (Bouguet, "Pyramidal implementation of the Lucas Kanade
feature tracker", 2001) with a forward-backward consistency check (Kalal et al., "Forward-Backward
Error: Automatic Detection of Tracking Failures", ICPR 2010), and re-detection of new corners in
the empty parts of the image.

Example:
    >>> curr_uv, ok = track_klt(prev_gray, curr_gray, prev_uv, KLTConfig())   # doctest: +SKIP
"""
from __future__ import annotations

import logging

import cv2
import numpy as np

from vslam.errors import VslamError
from vslam.features.config import KLTConfig
from vslam.features.detect import Features, describe_orb, grid_select

log = logging.getLogger(__name__)


def _gray(img: np.ndarray, what: str) -> np.ndarray:
    img = np.asarray(img)
    if img.ndim == 3 and img.shape[2] == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    if img.ndim != 2 or img.dtype != np.uint8:
        raise VslamError(f"KLT needs uint8 (H, W) images; {what} has shape {img.shape}, dtype {img.dtype}")
    return img


def track_klt(prev_gray: np.ndarray, curr_gray: np.ndarray, prev_uv: np.ndarray,
              cfg: KLTConfig | None = None, init_uv: np.ndarray | None = None
              ) -> tuple[np.ndarray, np.ndarray]:
    """Track ``prev_uv (N, 2)`` from ``prev_gray`` into ``curr_gray``.

    ``init_uv (N, 2)`` is an optional predicted position in the current image (e.g. from a motion
    model), used as the initial flow. A track is kept when LK converged both ways, the
    forward-backward error ``|prev_uv - backtrack(track(prev_uv))|`` is at most
    ``cfg.fb_threshold`` pixels, and the point stays ``cfg.border`` pixels inside the image.

    Returns ``(curr_uv (N, 2) float32, ok (N,) bool)``; rows with ``ok = False`` are undefined.
    """
    cfg = cfg or KLTConfig()
    prev_gray = _gray(prev_gray, "prev_gray")
    curr_gray = _gray(curr_gray, "curr_gray")
    p0 = np.ascontiguousarray(np.asarray(prev_uv, np.float32).reshape(-1, 1, 2))
    n = len(p0)
    if n == 0:
        return np.zeros((0, 2), np.float32), np.zeros(0, bool)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, cfg.max_iter, cfg.eps)
    flags = 0
    p1 = None
    if init_uv is not None:
        p1 = np.ascontiguousarray(np.asarray(init_uv, np.float32).reshape(-1, 1, 2)).copy()
        if len(p1) != n:
            raise VslamError(f"init_uv has {len(p1)} points but prev_uv has {n}")
        flags = cv2.OPTFLOW_USE_INITIAL_FLOW
    p1, ok = _pyr_lk(prev_gray, curr_gray, p0, p1, cfg, crit, flags)
    if cfg.fb_threshold > 0 and ok.any():
        idx = np.flatnonzero(ok)  # track back only what the forward pass found
        p0b = p0[idx].copy()  # start the backward pass at the origin (the inverse flow's answer)
        p0b, ok_b = _pyr_lk(curr_gray, prev_gray, np.ascontiguousarray(p1[idx]), p0b, cfg, crit,
                            cv2.OPTFLOW_USE_INITIAL_FLOW)
        fb = np.linalg.norm((p0b - p0[idx]).reshape(-1, 2), axis=1)
        ok[idx] = ok_b & (fb <= cfg.fb_threshold)
    uv = p1.reshape(-1, 2)
    h, w = curr_gray.shape
    b = cfg.border
    ok &= np.isfinite(uv).all(1)
    ok &= (uv[:, 0] >= b) & (uv[:, 1] >= b) & (uv[:, 0] <= w - 1 - b) & (uv[:, 1] <= h - 1 - b)
    return uv.astype(np.float32), ok


def _pyr_lk(prev_gray: np.ndarray, curr_gray: np.ndarray, p0: np.ndarray, p1: np.ndarray | None, cfg: KLTConfig,
            crit: tuple, flags: int) -> tuple[np.ndarray, np.ndarray]:
    """``cv2.calcOpticalFlowPyrLK`` of ``p0`` (from ``p1`` with ``OPTFLOW_USE_INITIAL_FLOW``) without
    its error output: ``(p1 (N, 1, 2) float32, status (N,) bool)``, the same as OpenCV's.

    ``OPTFLOW_LK_GET_MIN_EIGENVALS`` makes OpenCV skip the pass over every window at level 0 that
    computes the (unused) patch difference (0.4-0.6 ms of 7-8 ms for 2000 points, 11 x 11, 4
    levels). That pass also refused the points whose window's corner ``floor(p1 - (win - 1) / 2)``
    lies outside ``[-win, size)``; that test is repeated here, so the status is OpenCV's."""
    win = cfg.win_size
    p1, st, _ = cv2.calcOpticalFlowPyrLK(prev_gray, curr_gray, p0, p1, winSize=(win, win), maxLevel=cfg.max_level,
                                         criteria=crit, flags=flags | cv2.OPTFLOW_LK_GET_MIN_EIGENVALS,
                                         minEigThreshold=cfg.min_eig_threshold)
    corner = np.floor(p1.reshape(-1, 2) - np.float32((win - 1) * 0.5))
    h, w = curr_gray.shape
    inside = (corner[:, 0] >= -win) & (corner[:, 0] < w) & (corner[:, 1] >= -win) & (corner[:, 1] < h)
    return p1, st.reshape(-1).astype(bool) & inside


def occupancy_mask(shape: tuple[int, int], uv: np.ndarray, min_distance: float) -> np.ndarray:
    """A ``uint8`` mask (255 = free) with discs of radius ``min_distance`` cleared around ``uv``
    (drawn at once by dilating the point image with a disc, no per-point loop)."""
    h, w = shape
    occ = np.zeros((h, w), np.uint8)
    uv = np.asarray(uv, np.float64).reshape(-1, 2)
    if len(uv):
        xi = np.round(uv[:, 0]).astype(np.int64)
        yi = np.round(uv[:, 1]).astype(np.int64)
        inside = (xi >= 0) & (yi >= 0) & (xi < w) & (yi < h)
        occ[yi[inside], xi[inside]] = 255
        r = int(np.ceil(min_distance))
        if r > 0:
            occ = cv2.dilate(occ, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1)))
    return cv2.bitwise_not(occ)


def detect_new_points(gray: np.ndarray, existing_uv: np.ndarray, max_total: int,
                      min_distance: float = 15.0, cell_size: int = 40, quality: float = 0.001,
                      border: int = 20, describe: bool = False, method: str = "gftt",
                      fast_threshold: int = 10) -> np.ndarray | Features:
    """New corners where tracks have thinned out, so that ``len(existing) + new <= max_total``.

    Corners (Shi-Tomasi ``gftt`` or ``fast``) are searched only at least ``min_distance`` from
    every existing point and ``border`` from the image edge, then spread over a grid of
    ``cell_size`` cells (the best corner of each empty cell first; see :func:`grid_select`).

    Returns the new ``(K, 2) float32`` pixels, or with ``describe=True`` their :class:`Features`
    with ORB descriptors (points too close to the border for a descriptor are dropped).
    """
    gray = _gray(gray, "gray")
    existing_uv = np.asarray(existing_uv, np.float32).reshape(-1, 2)
    n_new = int(max_total) - len(existing_uv)
    empty = np.zeros((0, 2), np.float32)
    if n_new <= 0:
        return describe_orb(gray, empty) if describe else empty
    h, w = gray.shape
    mask = occupancy_mask((h, w), existing_uv, min_distance)
    b = max(int(border), 0)
    mask[:b] = 0
    mask[h - b :] = 0
    mask[:, :b] = 0
    mask[:, w - b :] = 0
    if method == "gftt":
        pts = cv2.goodFeaturesToTrack(gray, maxCorners=4 * n_new, qualityLevel=quality,
                                      minDistance=float(min_distance), mask=mask, blockSize=3)
        if pts is None:
            uv, score = empty, np.zeros(0)
        else:
            uv = pts.reshape(-1, 2).astype(np.float32)
            score = -np.arange(len(uv), dtype=np.float64)  # OpenCV returns them strongest first
    elif method == "fast":
        kps = cv2.FastFeatureDetector_create(fast_threshold, True).detect(gray, mask)
        uv = cv2.KeyPoint_convert(kps).reshape(-1, 2).astype(np.float32) if kps else empty
        score = np.array([k.response for k in kps], np.float64)
    else:
        raise VslamError(f"detect_new_points method={method!r} is unknown; use 'gftt' or 'fast'")
    if len(uv):
        uv = uv[np.sort(grid_select(uv, score, cell_size, n_new))]
    if describe:
        return describe_orb(gray, uv)
    return uv
