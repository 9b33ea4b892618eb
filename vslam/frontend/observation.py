"""What the tracker extracts from one frame: keypoints (distorted and undistorted), descriptors,
per-keypoint depth (RGB-D sampling or stereo matching) and their map-point associations.

KLT tracking and stereo-by-flow live here too (thin wrappers over OpenCV's pyramidal
Lucas-Kanade, Bouguet 2001, with a forward-backward check, Kalal et al. 2010); they use
``vslam.features`` when it provides them.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from vslam.geometry.camera import PinholeCamera


@dataclass
class Observation:
    """Per-frame keypoints and what is known about them (arrays of length N)."""

    uv: np.ndarray  # (N, 2) detected / tracked pixels in the (possibly distorted) image
    uv_undist: np.ndarray  # (N, 2) undistorted pixels (geometry uses these)
    descriptors: np.ndarray | None  # (N, D) or None (KLT tracks)
    octave: np.ndarray  # (N,) int
    depth: np.ndarray  # (N,) metres, NaN = unknown
    point_ids: np.ndarray  # (N,) map point id or -1
    binary: bool = True
    scale_factor: float = 1.2
    u_right: np.ndarray | None = None  # (N,) right-image u (stereo) or virtual right u (RGB-D), NaN = unknown
    anchor_kf: np.ndarray | None = None  # (N,) keyframe where a KLT track was born (-1 = none)
    anchor_idx: np.ndarray | None = None  # (N,) its keypoint index in that keyframe
    ref2d_idx: np.ndarray | None = None  # (N,) index in the 2D-2D reference frame (-1 = none)

    def __len__(self) -> int:
        return len(self.uv)

    def subset(self, idx: np.ndarray) -> "Observation":
        def s(a):
            return None if a is None else a[idx]

        return Observation(
            self.uv[idx], self.uv_undist[idx], s(self.descriptors), self.octave[idx], self.depth[idx],
            self.point_ids[idx], self.binary, self.scale_factor, s(self.u_right), s(self.anchor_kf), s(self.anchor_idx),
            s(self.ref2d_idx),
        )

    @staticmethod
    def concat(a: "Observation", b: "Observation") -> "Observation":
        def c(x, y, fill_shape=None):
            if x is None and y is None:
                return None
            if x is None or y is None:
                return None
            return np.concatenate([x, y])

        return Observation(
            np.concatenate([a.uv, b.uv]), np.concatenate([a.uv_undist, b.uv_undist]),
            c(a.descriptors, b.descriptors), np.concatenate([a.octave, b.octave]),
            np.concatenate([a.depth, b.depth]), np.concatenate([a.point_ids, b.point_ids]),
            a.binary, a.scale_factor, c(a.u_right, b.u_right), c(a.anchor_kf, b.anchor_kf), c(a.anchor_idx, b.anchor_idx),
            c(a.ref2d_idx, b.ref2d_idx),
        )

    @property
    def sigma(self) -> np.ndarray:
        """Measurement standard deviation in pixels, ``scale_factor ** octave``."""
        return np.power(self.scale_factor, self.octave.astype(float))


def sample_depth(depth_image: np.ndarray, uv: np.ndarray, min_depth: float, max_depth: float) -> np.ndarray:
    """Depth at the (distorted) detected pixels, nearest pixel; NaN where invalid or out of range."""
    h, w = depth_image.shape[:2]
    u = np.clip(np.rint(uv[:, 0]).astype(np.int64), 0, w - 1)
    v = np.clip(np.rint(uv[:, 1]).astype(np.int64), 0, h - 1)
    z = depth_image[v, u].astype(float)
    return np.where((z >= min_depth) & (z <= max_depth) & np.isfinite(z), z, np.nan)


def klt_track(
    prev_gray: np.ndarray, gray: np.ndarray, prev_uv: np.ndarray, init_uv: np.ndarray | None = None,
    window: int = 21, levels: int = 3, fb_threshold: float = 1.0, max_iter: int = 30, eps: float = 0.01,
) -> tuple[np.ndarray, np.ndarray]:
    """Track ``prev_uv`` into ``gray`` (:func:`vslam.features.klt.track_klt`); returns ``(uv (N, 2), ok (N,))``."""
    from vslam.features.config import KLTConfig
    from vslam.features.klt import track_klt

    if len(prev_uv) == 0:
        return np.zeros((0, 2)), np.zeros(0, bool)
    cfg = KLTConfig(win_size=window, max_level=levels, fb_threshold=fb_threshold, max_iter=max_iter, eps=eps)
    uv, ok = track_klt(prev_gray, gray, prev_uv, cfg, init_uv)
    return np.asarray(uv, dtype=float), np.asarray(ok, dtype=bool)


def stereo_by_flow(
    left: np.ndarray, right: np.ndarray, uv: np.ndarray, camera: PinholeCamera,
    max_depth_baselines: float = 60.0, max_dy: float = 1.5, min_depth: float = 0.1, init_disparity: np.ndarray | None = None,
    window: int = 11, levels: int = 4, max_iter: int = 5, eps: float = 0.1, flow: str = "lk2d",
    min_zncc: float = 0.5,
) -> tuple[np.ndarray, np.ndarray]:
    """Depth of left keypoints in a rectified pair; ``z = fx b / (u_l - u_r)``.

    Two stages: a pyramidal Lucas-Kanade from left into right finds each match, then
    :func:`vslam.features.stereo.refine_disparity_row` re-estimates the disparity with the shift
    restricted to the image row. ``flow="lk2d"``: OpenCV's 2-D tracker (Bouguet 2001, one way),
    whose matches must stay within ``max_dy`` rows; alone it is biased: on oriented texture the
    vertical shift it also solves for absorbs part of the disparity, which made KITTI 06 depths
    0.3-0.6 % too large (``tests/frontend/test_stereo_by_flow.py``). ``flow="row"``: the same
    pyramid with the disparity as the only unknown
    (:func:`vslam.features.stereo_search.match_rows`), cheaper and without that bias
    (``max_dy`` does not apply; instead the windows' normalized cross-correlation must reach
    ``min_zncc``).

    ``window`` / ``levels`` / ``max_iter`` / ``eps``: that pyramidal LK (``frontend.depth.stereo_flow_*``).
    Returns ``(depth (N,) NaN where unmatched, u_right (N,))``.
    """
    from vslam.features.stereo import refine_disparity_row

    n = len(uv)
    depth = np.full(n, np.nan)
    u_right = np.full(n, np.nan)
    if n == 0 or camera.baseline is None:
        return depth, u_right
    min_disp = camera.fx / max_depth_baselines
    if flow == "row":
        from vslam.features.stereo_search import match_rows

        d_flow, ok = match_rows(left, right, uv, init_disparity, window=window, levels=levels, max_iter=max_iter,
                                eps=eps, min_zncc=min_zncc)
    else:
        init = uv.copy()
        if init_disparity is not None:
            d0 = np.where(np.isfinite(init_disparity), init_disparity, 0.0)
            init[:, 0] -= d0
        # one way only, few iterations: the row refinement below sets the final value, and the row
        # constraint rejects the failures a backward check would
        uvr, ok = klt_track(left, right, uv, init_uv=init, window=window, levels=levels, fb_threshold=0.0,
                            max_iter=max_iter, eps=eps)
        ok &= np.abs(uvr[:, 1] - uv[:, 1]) < max_dy
        d_flow = uv[:, 0] - uvr[:, 0]
    ok &= d_flow > min_disp
    disp, ok_row = refine_disparity_row(left, right, uv, np.where(ok, d_flow, np.nan))
    ok &= ok_row & (disp > min_disp)
    z = np.where(ok, camera.fx * camera.baseline / np.where(ok, disp, 1.0), np.nan)
    ok &= (z >= min_depth)
    depth[ok] = z[ok]
    u_right[ok] = uv[ok, 0] - disp[ok]
    return depth, u_right


def stereo_pair_depth(frame, gray: np.ndarray, uv: np.ndarray, camera: PinholeCamera, depth_cfg,
                      init_disparity: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """:func:`stereo_by_flow` of ``uv`` in ``frame``'s rectified pair (``gray``: its left image in gray,
    the right one converted here) with the ``frontend.depth`` settings ``depth_cfg``: ``(depth,
    u_right)``. Needs ``frame.image_right``."""
    right = frame.image_right
    if right.ndim == 3:
        right = cv2.cvtColor(right, cv2.COLOR_BGR2GRAY)
    d = depth_cfg
    return stereo_by_flow(gray, right, uv, camera, d.stereo_max_depth_baselines, d.stereo_max_dy, d.min_depth,
                          init_disparity, d.stereo_flow_window, d.stereo_flow_levels, d.stereo_flow_max_iter,
                          d.stereo_flow_eps, d.stereo_flow, d.stereo_flow_min_zncc)


def detect_mask(shape: tuple[int, int], uv: np.ndarray, radius: int) -> np.ndarray:
    """A detection mask that is 0 within ``radius`` pixels of existing points, 255 elsewhere."""
    mask = np.full(shape[:2], 255, np.uint8)
    if len(uv):
        h, w = shape[:2]
        # paint squares (vectorized) instead of per-point circles
        u = np.clip(np.rint(uv[:, 0]).astype(int), 0, w - 1)
        v = np.clip(np.rint(uv[:, 1]).astype(int), 0, h - 1)
        small = np.zeros(((h + radius - 1) // radius + 1, (w + radius - 1) // radius + 1), np.uint8)
        small[v // radius, u // radius] = 1
        grown = cv2.dilate(small, np.ones((3, 3), np.uint8))
        big = np.kron(grown, np.ones((radius, radius), np.uint8))[:h, :w]
        mask[big > 0] = 0
    return mask
