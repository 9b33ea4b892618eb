"""The compiled row-constrained disparity refinement (vslam.features.stereo_kernels, behind
``refine_disparity_row``) against a plain NumPy version of the same equations (the oracle, no
BLAS call), on 8-bit images, synthetic and real (KITTI 06).

Where the two can differ, and by how much (the tolerances below): for 8-bit images every window
sum but one is a sum of integers, halves or quarters below 2^53, exact in float64 in any order, and the
left window mean is the same exact sum divided by ``n`` on both sides. The one inexact sum is
``C = sum I_l g`` over the zero-mean left window: the kernel adds its ``n = (2w+1)^2`` terms in
loop order, NumPy pairwise, each within ``gamma_n sum|I_l g|`` of the exact value
(``gamma_n = n u / (1 - n u)``, ``u = 2^-53``; Higham 2002, eq. 4.4), so the two differ by at most
``2 gamma_n sum|I_l g|``. A Gauss-Newton step is ``(... - C) / hgg``, so one step moves by at
most ``dC / hgg`` and the result by at most ``iters`` times that (each step starts from the other
side's ``d``, and the window sums are linear in ``d`` between integer shifts with slopes bounded
by the same sums: a factor 2 more per step is allowed). The oracle returns that bound per point;
a converged flag may differ only where a decision (last step against ``tol``, distance from the
start against ``max_change``, texture against 1e-6) lies within the bound of its threshold.
"""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from vslam.features import FeatureConfig, create_detector
from vslam.features import stereo_kernels
from vslam.features.stereo import refine_disparity_row
from vslam.frontend.observation import klt_track
from vslam.stream import KERNEL_MODULES

U64 = 2.0 ** -53


def _gamma(n: int) -> float:
    return n * U64 / (1 - n * U64)


def _refine_reference(left, right, uv, disp0, half_window=5, iters=5, max_change=3.0, tol=0.25):
    """``refine_disparity_row`` in NumPy, float64: ``(d, ok, bound, margin)`` where ``bound`` is the
    largest difference rounding allows between this and the kernel (module docstring) and
    ``margin`` the distance of the point's closest flag decision from its threshold."""
    uv = np.asarray(uv, np.float64).reshape(-1, 2)
    d0 = np.asarray(disp0, np.float64).reshape(-1)
    n = len(uv)
    disp, ok = d0.copy(), np.zeros(n, bool)
    bound, margin = np.zeros(n), np.full(n, np.inf)
    h, wid = left.shape[:2]
    w = int(half_window)
    W = 2 * w + 1
    max_change = np.broadcast_to(np.asarray(max_change, np.float64), (n,))
    M = int(np.ceil(float(np.max(max_change)))) + 1 if n else 0
    S = W + 2 * M
    for k in range(n):
        ul, vl = int(np.rint(uv[k, 0])), int(np.rint(uv[k, 1]))
        if not np.isfinite(d0[k]):
            continue
        x0 = ul - int(np.rint(d0[k])) - w - M
        if not (vl - w >= 0 and vl + w < h and ul - w >= 0 and ul + w < wid and x0 >= 1 and x0 + S + 1 <= wid):
            continue
        pl = left[vl - w:vl + w + 1, ul - w:ul + w + 1].astype(np.float64)
        pl = pl - pl.sum() / pl.size
        ext = right[vl - w:vl + w + 1, x0 - 1:x0 + S + 1].astype(np.float64)
        st, gr = ext[:, 1:-1], 0.5 * (ext[:, 2:] - ext[:, :-2])
        gr1 = np.concatenate([gr[:, 1:], np.zeros((W, 1))], axis=1)  # g(s + 1), 0 past the strip
        st1 = np.concatenate([st[:, 1:], np.zeros((W, 1))], axis=1)
        tabs = []
        for j in range(S - W + 1):
            c = slice(j, j + W)
            tabs.append([st[:, c].sum(), gr[:, c].sum(), (st[:, c] * gr[:, c]).sum(), (gr[:, c] ** 2).sum(),
                         (st[:, c] * gr1[:, c]).sum(), (st1[:, c] * gr[:, c]).sum(), (gr[:, c] * gr1[:, c]).sum(),
                         (pl * gr[:, c]).sum(), np.abs(pl * gr[:, c]).sum()])
        T = np.array(tabs).T
        dC = 2 * _gamma(W * W) * T[8].max()
        d, good, step, hmin, hlow = d0[k], True, 0.0, np.inf, np.inf
        base = float(ul - w - x0)
        for _ in range(iters):
            pos = base - d
            kk = int(np.floor(pos))
            good &= 0 <= kk and kk + 1 <= S - W
            kk = min(max(kk, 0), S - W - 1)
            a = pos - kk
            b = 1.0 - a
            s_ig = b * b * T[2, kk] + a * b * (T[4, kk] + T[5, kk]) + a * a * T[2, kk + 1]
            s_gg = b * b * T[3, kk] + 2 * a * b * T[6, kk] + a * a * T[3, kk + 1]
            s_i, s_g = b * T[0, kk] + a * T[0, kk + 1], b * T[1, kk] + a * T[1, kk + 1]
            s_lg = b * T[7, kk] + a * T[7, kk + 1]
            hgg = s_gg - s_g * s_g / (W * W)
            hmin = min(hmin, abs(hgg - 1e-6))  # the texture decision's margin
            if hgg <= 1e-6:
                good, step = False, 0.0
                continue
            hlow = min(hlow, hgg)
            step = float(np.clip((s_ig - s_i * s_g / (W * W) - s_lg) / hgg, -1.0, 1.0))
            d += step
        bound[k] = iters * 2.0 ** iters * dC / hlow if np.isfinite(hlow) else 0.0
        margin[k] = min(abs(abs(step) - tol), abs(abs(d - d0[k]) - max_change[k]), hmin)
        ok[k] = good and abs(step) < tol and abs(d - d0[k]) <= max_change[k]
        disp[k] = d if ok[k] else d0[k]
    return disp, ok, bound, margin


def _assert_close(left, right, uv, d0, **kw):
    """Kernel and oracle agree within the rounding bound; flags differ only at a threshold."""
    d, ok = refine_disparity_row(left, right, uv, d0, **kw)
    d_ref, ok_ref, bound, margin = _refine_reference(left, right, uv, d0, **kw)
    flip = ok != ok_ref
    assert np.all(margin[flip] <= bound[flip]), (np.flatnonzero(flip), margin[flip], bound[flip])
    both = ok & ok_ref
    np.testing.assert_array_equal(np.isnan(d[~both]), np.isnan(d_ref[~both]))
    assert np.all(np.abs(d[both] - d_ref[both]) <= bound[both]), np.max(np.abs(d[both] - d_ref[both]) - bound[both])
    return ok


@pytest.mark.parametrize("disparity", [12.3, 30.85, 47.5])
@pytest.mark.parametrize("kw", [{}, {"half_window": 3, "iters": 3}, {"max_change": 1.5, "tol": 0.1}])
def test_refine_rows_matches_oracle_synthetic(gravel, shift_image, disparity, kw):
    """Shifted gravel texture, starts up to 2.5 px off, points up to the image borders (refused
    ones included) and NaN starts: the kernel matches the oracle within the rounding bound."""
    rng = np.random.default_rng(7)
    right = shift_image(gravel, -disparity, 0.0)
    uv = np.column_stack([rng.uniform(0, 511, 400), rng.uniform(0, 511, 400)])
    d0 = disparity + rng.uniform(-2.5, 2.5, len(uv))
    d0[::37] = np.nan
    ok = _assert_close(gravel, right, uv, d0, **kw)
    assert 0.4 < ok.mean() < 0.95  # converged points and refused ones (borders, NaN, far starts)


def test_refine_rows_matches_oracle_per_point_max_change(gravel, shift_image):
    rng = np.random.default_rng(3)
    right = shift_image(gravel, -20.4, 0.0)
    uv = np.column_stack([rng.uniform(40, 470, 300), rng.uniform(10, 500, 300)])
    d0 = 20.4 + rng.uniform(-3.0, 3.0, len(uv))
    ok = _assert_close(gravel, right, uv, d0, max_change=rng.choice([1.0, 1.2, 2.4, 4.8], len(uv)))
    assert 0.3 < ok.mean() < 0.98  # some starts are farther than their bound allows


def test_refine_rows_float_images_close(gravel, shift_image):
    """Non-8-bit images go through float32 like before; the sums are no longer exact there, so
    only agreement to rounding is asked."""
    rng = np.random.default_rng(5)
    left = gravel.astype(np.float32) * 0.37
    right = shift_image(gravel, -15.3, 0.0).astype(np.float32) * 0.37
    uv = np.column_stack([rng.uniform(40, 470, 300), rng.uniform(10, 500, 300)])
    d0 = 15.3 + rng.uniform(-2.0, 2.0, len(uv))
    d, ok = refine_disparity_row(left, right, uv, d0)
    d_ref, ok_ref, _, _ = _refine_reference(left, right, uv, d0)
    assert (ok == ok_ref).mean() > 0.99 and ok.mean() > 0.9
    np.testing.assert_allclose(d[ok & ok_ref], d_ref[ok & ok_ref], atol=1e-4)


def test_refine_rows_empty_and_registered():
    d, ok = refine_disparity_row(np.zeros((20, 40), np.uint8), np.zeros((20, 40), np.uint8), np.zeros((0, 2)), np.zeros(0))
    assert d.shape == (0,) and ok.shape == (0,)
    assert "vslam.features.stereo_kernels" in KERNEL_MODULES
    stereo_kernels.warm()


@pytest.mark.shared
def test_refine_rows_matches_oracle_kitti(shared_data):
    """KITTI 06 pairs, the project's keypoints and the tracker's LK starts (as ``stereo_by_flow``):
    disparities within the rounding bound, flags equal away from thresholds, over a thousand
    refined points per frame."""
    seq = shared_data / "kitti_odometry/sequences/06"
    det = create_detector(FeatureConfig(n_features=2000))
    for i in (0, 30):
        left = cv2.imread(str(seq / f"image_0/{i:06d}.png"), cv2.IMREAD_GRAYSCALE)
        right = cv2.imread(str(seq / f"image_1/{i:06d}.png"), cv2.IMREAD_GRAYSCALE)
        uv = np.asarray(det.detect(left).uv, float)
        uvr, ok = klt_track(left, right, uv, init_uv=uv.copy(), window=11, levels=4, fb_threshold=0.0, max_iter=5,
                            eps=0.1)
        ok &= (np.abs(uvr[:, 1] - uv[:, 1]) < 1.5) & (uv[:, 0] - uvr[:, 0] > 707.0912 / 60.0)
        ok_row = _assert_close(left, right, uv, np.where(ok, uv[:, 0] - uvr[:, 0], np.nan))
        assert ok_row.sum() > 900
