"""Left-right feature matching for a rectified stereo pair, with sub-pixel disparity refinement
(ORB-SLAM2's ``Frame::ComputeStereoMatches``, Mur-Artal & Tardos, T-RO 2017, Sec. III-A).

For every left keypoint the candidates are right keypoints on the same row band
(``|v_l - v_r| <= max_row_diff * scale(octave_r)``), inside the disparity range and within
``octave_tolerance`` octaves; the closest descriptor wins (ratio test against the second). The
match is then refined by SAD block matching of an 11x11 patch (intensities taken relative to the
patch centre) along the row at the keypoint's pyramid level, and a parabola through the SAD
minimum and its two neighbours gives the sub-pixel offset
``delta = (s[-1] - s[+1]) / (2 (s[-1] + s[+1] - 2 s[0]))``. That parabola is biased on a V-shaped
SAD curve (0.2-0.3 px median error on an exactly shifted texture), so by default
(``StereoConfig.subpixel = "lk"``) the disparity is then refined by a 1-D Lucas-Kanade step at
full resolution (0.02 px median on the same test); see :func:`refine_disparity_row`.

Depth is then ``z = fx * baseline / (u_left - u_right)``; see :func:`stereo_depth`.

:func:`refine_disparity_row` is the same 1-D (row-constrained) LK for any left pixels and
initial disparities, fast enough for every frame (window sums tabulated once per point); the
tracker's ``stereo_by_flow`` uses it after a 2-D pyramidal LK, whose free vertical shift biases
disparities on oriented texture.
"""
from __future__ import annotations

import logging

import numpy as np

from vslam.errors import CalibrationError, VslamError
from vslam.features.config import StereoConfig
from vslam.features.detect import Features, build_pyramid
from vslam.features.match import descriptor_distances

log = logging.getLogger(__name__)


def stereo_depth(u_left: np.ndarray, u_right: np.ndarray, fx: float, baseline: float) -> np.ndarray:
    """Depth ``z = fx * b / (u_l - u_r)`` in metres (inf where the disparity is <= 0)."""
    disp = np.asarray(u_left, np.float64) - np.asarray(u_right, np.float64)
    with np.errstate(divide="ignore"):
        return np.where(disp > 0, fx * baseline / np.where(disp > 0, disp, 1.0), np.inf)


def _candidate_pairs(v_l: np.ndarray, v_r: np.ndarray, band_max: float) -> tuple[np.ndarray, np.ndarray]:
    """All ``(i, j)`` with ``|v_l[i] - v_r[j]| <= band_max``, without an N x M matrix: sort the
    right rows, find each left row's range by ``searchsorted``, expand the ranges."""
    order = np.argsort(v_r, kind="stable")
    vs = v_r[order]
    lo = np.searchsorted(vs, v_l - band_max, side="left")
    hi = np.searchsorted(vs, v_l + band_max, side="right")
    cnt = hi - lo
    total = int(cnt.sum())
    if total == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    li = np.repeat(np.arange(len(v_l)), cnt)
    starts = np.repeat(lo - np.r_[0, np.cumsum(cnt)[:-1]], cnt)
    rj = order[starts + np.arange(total)]
    return li, rj


def _refine_sad(left_levels: list[np.ndarray], right_levels: list[np.ndarray], u_l: np.ndarray,
                v_l: np.ndarray, u_r: np.ndarray, octave: np.ndarray, scale_factor: float,
                w: int, L: int, cost: str = "sad") -> tuple[np.ndarray, np.ndarray]:
    """Sub-pixel ``u_right`` by SAD (or SSD) along the row at each keypoint's level (module doc).

    Returns ``(u_right_refined, ok)``; ``ok`` is False when the patch leaves the image, the SAD
    minimum is at the end of the search range, or the parabola offset is not in ``[-1, 1]``."""
    n = len(u_l)
    out = np.full(n, np.nan)
    ok = np.zeros(n, bool)
    dx = np.arange(-w, w + 1)
    shifts = np.arange(-L, L + 1)
    for lvl in np.unique(octave):
        sel = np.flatnonzero(octave == lvl)
        if lvl >= len(left_levels):
            continue
        s = scale_factor**lvl
        img_l = left_levels[lvl]
        img_r = right_levels[lvl]
        h, wid = img_l.shape
        ul = np.round((u_l[sel] + 0.5) / s - 0.5).astype(np.int64)  # level pixel (centre-correct)
        vl = np.round((v_l[sel] + 0.5) / s - 0.5).astype(np.int64)
        ur = np.round((u_r[sel] + 0.5) / s - 0.5).astype(np.int64)
        inside = (vl - w >= 0) & (vl + w < h) & (ul - w >= 0) & (ul + w < wid) \
            & (ur - w - L - 1 >= 0) & (ur + w + L + 1 < wid)
        sel, ul, vl, ur = sel[inside], ul[inside], vl[inside], ur[inside]
        if len(sel) == 0:
            continue
        rows = vl[:, None, None] + dx[None, :, None]  # (K, 2w+1, 1)
        patch_l = img_l[rows, ul[:, None, None] + dx[None, None, :]].astype(np.float32)  # (K, 2w+1, 2w+1)
        patch_l = patch_l - patch_l[:, w : w + 1, w : w + 1]
        ext = np.arange(-w - L, w + L + 1)  # strip columns around ur
        strip = img_r[rows, ur[:, None, None] + ext[None, None, :]].astype(np.float32)  # (K, 2w+1, 2w+1+2L)
        W = 2 * w + 1
        sad = np.empty((len(sel), 2 * L + 1), np.float32)
        for j in range(2 * L + 1):  # 11 shifts; each a contiguous (K, W, W) slice
            win = strip[:, :, j : j + W]
            diff = (win - win[:, w : w + 1, w : w + 1]) - patch_l  # both relative to their centre
            sad[:, j] = (diff * diff).sum(axis=(1, 2)) if cost == "ssd" else np.abs(diff).sum(axis=(1, 2))
        best = np.argmin(sad, axis=1)
        interior = (best > 0) & (best < 2 * L)
        b = np.clip(best, 1, 2 * L - 1)
        k = np.arange(len(sel))
        s1, s2, s3 = sad[k, b - 1], sad[k, b], sad[k, b + 1]
        denom = 2.0 * (s1 + s3 - 2.0 * s2)
        with np.errstate(divide="ignore", invalid="ignore"):
            delta = np.where(denom > 0, (s1 - s3) / denom, np.nan)
        good = interior & np.isfinite(delta) & (np.abs(delta) <= 1.0)
        # disparity in level pixels, times the level scale; u_right = u_left - disparity
        ur_ref = u_l[sel] - (ul - (ur + shifts[b] + delta)) * s
        out[sel[good]] = ur_ref[good]
        ok[sel[good]] = True
    return out, ok


def refine_disparity_row(left: np.ndarray, right: np.ndarray, uv: np.ndarray, disp0: np.ndarray,
                         half_window: int = 5, iters: int = 5, max_change: float | np.ndarray = 3.0,
                         tol: float = 0.25) -> tuple[np.ndarray, np.ndarray]:
    """Row-constrained (1-D) Lucas-Kanade refinement of stereo disparities at full resolution.

    Gauss-Newton on ``E(d) = sum_window ((I_r(x - d, y) - mean) - (I_l(x, y) - mean))^2`` over the
    disparity ``d`` alone (Lucas & Kanade 1981 with the shift restricted to the rectified
    epipolar line; zero-mean windows absorb a brightness offset between the cameras):
    ``delta = sum(r g) / sum((g - mean g)^2)`` with ``g = dI_r/dx`` (central differences) and the
    right image interpolated linearly along the row.

    Why the row constraint matters: a 2-D tracker (OpenCV's pyramidal LK) also solves for a
    vertical shift, and on oriented texture the ``sum gx gy`` term of its 2x2 system couples
    the two: ``d_2D - d_row = (sum gx gy / sum gx^2) dy``. On KITTI 06 (|dy| up to 1 px) that
    shrinks disparities by 0.11 px (0.3-0.6 %) on average against this estimate and against
    OpenCV's SGBM, so depths, and the odometry's scale, came out that much too large.

    Cost: every window sum a step needs (``sum I_r g``, ``sum g g``, ``sum I_l g`` ...) is
    computed once per point for every integer shift of a strip cut around ``disp0``; with the
    right window at ``k + a`` (``k`` integer, ``0 <= a < 1``) linear interpolation makes each sum a
    quadratic in ``a`` of those tables, so an iteration is O(1) per point.

    The left window is centred on the keypoint's nearest pixel, so the disparity is that of
    ``round(uv)`` (at most half a pixel away); ``u_right = u - d``.

    Args:
        left, right: rectified grayscale images (H, W).
        uv: (N, 2) left pixels.
        disp0: (N,) initial disparities in pixels (NaN = skip), e.g. from a pyramidal tracker.
        half_window: window half size (5 -> 11x11).
        iters: Gauss-Newton iterations.
        max_change: the result must stay within this many pixels of ``disp0`` (a number, or one
            per point, e.g. the keypoint's pyramid scale).
        tol: the last step must be smaller than this (pixels) for the point to count as converged.

    Returns:
        ``(disparity (N,), ok (N,) bool)``; ``disparity`` is ``disp0`` where not ``ok``.

    Example:
        >>> d, ok = refine_disparity_row(left, right, uv, d_lk)   # doctest: +SKIP
    """
    uv = np.asarray(uv, np.float64).reshape(-1, 2)
    d0 = np.asarray(disp0, np.float64).reshape(-1)
    n = len(uv)
    disp = d0.copy()
    ok = np.zeros(n, bool)
    if n == 0:
        return disp, ok
    h, wid = left.shape[:2]
    w = int(half_window)
    W = 2 * w + 1
    N = float(W * W)
    max_change = np.broadcast_to(np.asarray(max_change, np.float64), (n,))
    M = int(np.ceil(float(np.max(max_change)))) + 1  # strip margin each side of the initial window
    S = W + 2 * M  # strip width: columns of the right image cut per point
    ul = np.rint(uv[:, 0]).astype(np.int64)
    vl = np.rint(uv[:, 1]).astype(np.int64)
    finite = np.isfinite(d0)
    x0 = ul - np.rint(np.where(finite, d0, 0.0)).astype(np.int64) - w - M  # right column of strip column 0
    valid = finite & (vl - w >= 0) & (vl + w < h) & (ul - w >= 0) & (ul + w < wid) & (x0 >= 1) & (x0 + S + 1 <= wid)
    sel = np.flatnonzero(valid)
    if len(sel) == 0:
        return disp, ok
    tables = _row_window_sums(left, right, ul[sel], vl[sel], x0[sel], w, S)
    base = (ul[sel] - w - x0[sel]).astype(np.float64)  # strip column of the window start at d = 0
    d, good, step = _row_gauss_newton(tables, base, d0[sel], iters, N, S - W)
    good &= (np.abs(step) < tol) & (np.abs(d - d0[sel]) <= max_change[sel])
    disp[sel] = np.where(good, d, d0[sel])
    ok[sel] = good
    return disp, ok


def _row_window_sums(left: np.ndarray, right: np.ndarray, ul: np.ndarray, vl: np.ndarray, x0: np.ndarray, w: int,
                     S: int) -> tuple[np.ndarray, ...]:
    """The window sums of :func:`refine_disparity_row` for every integer start ``j`` of the right
    window in each point's strip (``S`` columns from right column ``x0``; left window ``(2w+1)^2``
    centred on ``(ul, vl)``, zero-mean): ``A = sum I_r``, ``B = sum g``, ``P00 = sum I_r(j) g(j)``,
    ``Q00 = sum g(j) g(j)``, ``P01 = sum I_r(j) g(j+1)``, ``P10 = sum I_r(j+1) g(j)``,
    ``Q01 = sum g(j) g(j+1)``, ``C = sum I_l g(j)``, each ``(K, S - W + 1)``."""
    W = 2 * w + 1
    K = len(ul)
    wid = left.shape[1]
    dx = np.arange(-w, w + 1)
    rows = (vl[:, None] + dx[None, :])[:, :, None] * wid  # (K, W, 1) flat offsets of the window rows
    pl = np.take(np.ascontiguousarray(left).reshape(-1), rows + (ul[:, None] + dx[None, :])[:, None, :])
    pl = pl.astype(np.float32)  # (K, W, W)
    pl -= pl.mean(axis=(1, 2), keepdims=True)
    ext = np.take(np.ascontiguousarray(right).reshape(-1), rows + (x0[:, None] + np.arange(-1, S + 1)[None, :])[:, None, :])
    ext = ext.astype(np.float32)  # (K, W, S+2)
    st = ext[:, :, 1:-1]  # I_r on the strip
    gr = 0.5 * (ext[:, :, 2:] - ext[:, :, :-2])  # dI_r/dx on the strip

    # per-column sums over the window rows (the shifted products padded to S columns), then
    # window sums for every integer start j = 0..S-W
    col = np.zeros((7, K, S), np.float32)
    np.einsum("krc->kc", st, out=col[0])  # sum I_r
    np.einsum("krc->kc", gr, out=col[1])  # sum g
    np.einsum("krc,krc->kc", st, gr, out=col[2])  # sum I_r(j) g(j)
    np.einsum("krc,krc->kc", gr, gr, out=col[3])  # sum g(j) g(j)
    np.einsum("krc,krc->kc", st[:, :, :-1], gr[:, :, 1:], out=col[4, :, :-1])  # sum I_r(j) g(j+1)
    np.einsum("krc,krc->kc", st[:, :, 1:], gr[:, :, :-1], out=col[5, :, :-1])  # sum I_r(j+1) g(j)
    np.einsum("krc,krc->kc", gr[:, :, :-1], gr[:, :, 1:], out=col[6, :, :-1])  # sum g(j) g(j+1)
    col = col.astype(np.float64)
    win = np.empty((7, K, S - W + 1))  # running window sums
    win[:, :, 0] = col[:, :, :W].sum(axis=2)
    for j in range(1, S - W + 1):
        win[:, :, j] = win[:, :, j - 1] + col[:, :, j + W - 1] - col[:, :, j - 1]
    # sum I_l g(j) for every start j: all column pairs (batched W x S matmul), then the diagonals
    cross = np.matmul(pl.transpose(0, 2, 1), gr)  # (K, W, S): [c, s] = sum_rows I_l(c) g(s)
    cw = np.arange(W)[:, None]
    C = cross[:, cw, np.arange(S - W + 1)[None, :] + cw].sum(axis=1)  # (K, S-W+1)
    return (*win, C)  # A, B, P00, Q00, P01, P10, Q01, C: each (K, S-W+1)


def _row_gauss_newton(tables: tuple[np.ndarray, ...], base: np.ndarray, d_init: np.ndarray, iters: int, N: float,
                      last_start: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Gauss-Newton on the disparities ``d`` from ``d_init`` with the window sums of
    :func:`_row_window_sums` (window start ``base - d`` in strip columns, at most ``last_start``),
    each sum linearly interpolated between integer starts. Returns ``(d, good, last step)``."""
    A, B, P00, Q00, P01, P10, Q01, C = tables
    K = len(d_init)
    kr = np.arange(K)
    d = d_init.copy()
    good = np.ones(K, bool)
    step = np.zeros(K)
    for _ in range(iters):
        pos = base - d  # window start in strip columns (fractional)
        k = np.floor(pos).astype(np.int64)
        good &= (k >= 0) & (k + 1 <= last_start)
        k = np.clip(k, 0, last_start - 1)
        a = pos - k
        b = 1.0 - a
        s_ig = b * b * P00[kr, k] + a * b * (P01[kr, k] + P10[kr, k]) + a * a * P00[kr, k + 1]
        s_gg = b * b * Q00[kr, k] + 2.0 * a * b * Q01[kr, k] + a * a * Q00[kr, k + 1]
        s_i = b * A[kr, k] + a * A[kr, k + 1]
        s_g = b * B[kr, k] + a * B[kr, k + 1]
        s_lg = b * C[kr, k] + a * C[kr, k + 1]
        hgg = s_gg - s_g * s_g / N  # sum (g - mean g)^2
        flat = hgg <= 1e-6
        good &= ~flat
        # r = (I_r - mean) - I_l (I_l zero-mean); I_r(x - d - delta) ~ I_r(x - d) - delta g
        # -> delta = sum(r g) / sum((g - mean g)^2)
        srg = s_ig - s_i * s_g / N - s_lg
        step = np.clip(srg / np.where(flat, 1.0, hgg), -1.0, 1.0)
        d += np.where(flat, 0.0, step)
    return d, good, step


def match_stereo_descriptors(left: Features, right: Features, cfg: StereoConfig,
                             max_disparity: float) -> tuple[np.ndarray, np.ndarray]:
    """The descriptor stage of :func:`match_stereo`: ``(left_idx, right_idx)`` of the best right
    keypoint on the row band of each left keypoint (ratio test, each right keypoint once)."""
    max_disp = max_disparity
    empty = (np.zeros(0, np.int64), np.zeros(0, np.int64))
    sf = float(left.scale_factor)
    u_l, v_l = left.uv[:, 0].astype(np.float64), left.uv[:, 1].astype(np.float64)
    u_r, v_r = right.uv[:, 0].astype(np.float64), right.uv[:, 1].astype(np.float64)
    oct_l = left.octave.astype(np.int64)
    oct_r = right.octave.astype(np.int64)
    pairs_l, pairs_r = [], []
    for o in np.unique(oct_r):  # one band per right octave (<= n_levels passes)
        r_idx = np.flatnonzero(oct_r == o)
        l_idx = np.flatnonzero(np.abs(oct_l - o) <= cfg.octave_tolerance)
        if len(l_idx) == 0:
            continue
        band = cfg.max_row_diff * sf ** float(o)
        a, b = _candidate_pairs(v_l[l_idx], v_r[r_idx], band)
        pairs_l.append(l_idx[a])
        pairs_r.append(r_idx[b])
    if not pairs_l:
        return empty
    li, rj = np.concatenate(pairs_l), np.concatenate(pairs_r)
    disp = u_l[li] - u_r[rj]
    ok = (disp >= cfg.min_disparity) & (disp <= max_disp)
    li, rj = li[ok], rj[ok]
    if len(li) == 0:
        return empty
    d = descriptor_distances(left.descriptors[li], right.descriptors[rj], left.binary)
    # best and second-best per left keypoint: sort by (left, distance, right)
    if left.binary:  # integer distances <= 8 * D: one unique int64 key, quicksort
        nr = len(right)
        o = np.argsort((li * (8 * left.descriptors.shape[1] + 1) + d.astype(np.int64)) * nr + rj)
    else:
        o = np.lexsort((rj, d, li))
    li, rj, d = li[o], rj[o], d[o]
    first = np.r_[True, li[1:] != li[:-1]]
    fi = np.flatnonzero(first)
    has_second = np.r_[fi[1:] - fi[:-1] > 1, len(li) - fi[-1] > 1]
    second = np.where(has_second, d[np.minimum(fi + 1, len(d) - 1)], np.inf)
    best_l, best_r, best_d = li[fi], rj[fi], d[fi]
    max_dist = cfg.max_distance if cfg.max_distance is not None else (100.0 if left.binary else np.inf)
    keep = (best_d <= max_dist) & ((best_d < cfg.ratio * second) if cfg.ratio < 1.0 else True)
    # each right keypoint used once: smallest distance wins
    best_l, best_r, best_d = best_l[keep], best_r[keep], best_d[keep]
    o = np.lexsort((best_l, best_d))
    _, uniq = np.unique(best_r[o], return_index=True)
    sel = np.sort(o[uniq])
    best_l, best_r = best_l[sel], best_r[sel]
    return best_l.astype(np.int64), best_r.astype(np.int64)


def match_stereo(left: Features, right: Features, cfg: StereoConfig | None = None,
                 left_gray: np.ndarray | None = None, right_gray: np.ndarray | None = None,
                 fx: float | None = None, baseline: float | None = None, camera=None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Match left keypoints to the right image of a rectified pair.

    Args:
        left, right: features of the two images (same detector).
        cfg: thresholds (:class:`StereoConfig`).
        left_gray, right_gray: the images; when both are given (and ``cfg.refine``) the
            disparity is refined to sub-pixel precision and matches whose refinement fails are
            dropped. Without them ``u_right`` is the matched right keypoint's ``u``.
        fx, baseline / camera: used only to derive ``max_disparity = fx * b / cfg.min_depth``
            when ``cfg.max_disparity`` is None (``camera`` is a PinholeCamera with a baseline).

    Returns ``(left_idx (K,) int64, u_right (K,) float64)``, sorted by ``left_idx``;
    ``depth = fx * baseline / (left.uv[left_idx, 0] - u_right)``.
    """
    cfg = cfg or StereoConfig()
    empty = (np.zeros(0, np.int64), np.zeros(0, np.float64))
    if len(left) == 0 or len(right) == 0:
        return empty
    if left.binary != right.binary or left.descriptors.shape[1] != right.descriptors.shape[1]:
        raise VslamError("left and right features come from different descriptors")
    if camera is not None:
        fx = camera.fx if fx is None else fx
        baseline = camera.baseline if baseline is None else baseline
    max_disp = cfg.max_disparity
    if max_disp is None:
        if fx is not None and baseline is not None:
            if baseline <= 0:
                raise CalibrationError(f"stereo baseline must be > 0 metres, got {baseline}")
            max_disp = fx * baseline / cfg.min_depth
        else:
            max_disp = float(max(left.uv[:, 0].max(), right.uv[:, 0].max()) + 1.0)
    best_l, best_r = match_stereo_descriptors(left, right, cfg, max_disp)
    if len(best_l) == 0:
        return empty
    sf = float(left.scale_factor)
    u_l, v_l = left.uv[:, 0].astype(np.float64), left.uv[:, 1].astype(np.float64)
    u_r = right.uv[:, 0].astype(np.float64)
    u_right = u_r[best_r].copy()
    if cfg.refine and left_gray is not None and right_gray is not None:
        if left_gray.shape != right_gray.shape:
            raise VslamError(f"stereo images differ in size: {left_gray.shape} vs {right_gray.shape}")
        n_lv = int(max(left.octave.max(), right.octave.max())) + 1
        pl = build_pyramid(np.asarray(left_gray), n_lv, sf)
        pr = build_pyramid(np.asarray(right_gray), n_lv, sf)
        ref, good = _refine_sad(pl, pr, u_l[best_l], v_l[best_l], u_right, left.octave[best_l].astype(np.int64),
                                sf, cfg.sad_window, cfg.sad_search)
        if cfg.subpixel == "lk":
            d0 = u_l[best_l] - ref
            # accept the LK result where it stays within one level pixel of the SAD estimate
            scale = np.power(sf, left.octave[best_l].astype(np.float64))
            uv_l = np.stack([u_l[best_l], v_l[best_l]], 1)
            d_lk, ok_lk = refine_disparity_row(pl[0], pr[0], uv_l, np.where(good, d0, np.nan),
                                               cfg.lk_window, iters=10, max_change=scale)
            ok_lk &= good
            ref = np.where(ok_lk, u_l[best_l] - d_lk, ref)
            good = ok_lk
        disp_ref = u_l[best_l] - ref
        good &= (disp_ref >= cfg.min_disparity) & (disp_ref <= max_disp)
        best_l, u_right = best_l[good], ref[good]
    return best_l.astype(np.int64), u_right.astype(np.float64)
