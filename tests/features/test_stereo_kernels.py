"""The compiled row-constrained disparity refinement (vslam.features.stereo_kernels, behind
``refine_disparity_row``) against the tabulated NumPy version it replaced (kept here as the oracle):
bit-identical on 8-bit images, synthetic and real (KITTI 06)."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from vslam.features import FeatureConfig, create_detector
from vslam.features import stereo_kernels
from vslam.features.stereo import refine_disparity_row
from vslam.frontend.observation import klt_track
from vslam.stream import KERNEL_MODULES


def _refine_reference(left, right, uv, disp0, half_window=5, iters=5, max_change=3.0, tol=0.25):
    """``refine_disparity_row`` as it was in NumPy (window-sum tables for all points at once)."""
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
    M = int(np.ceil(float(np.max(max_change)))) + 1
    S = W + 2 * M
    ul = np.rint(uv[:, 0]).astype(np.int64)
    vl = np.rint(uv[:, 1]).astype(np.int64)
    finite = np.isfinite(d0)
    x0 = ul - np.rint(np.where(finite, d0, 0.0)).astype(np.int64) - w - M
    valid = finite & (vl - w >= 0) & (vl + w < h) & (ul - w >= 0) & (ul + w < wid) & (x0 >= 1) & (x0 + S + 1 <= wid)
    sel = np.flatnonzero(valid)
    if len(sel) == 0:
        return disp, ok
    tables = _row_window_sums(left, right, ul[sel], vl[sel], x0[sel], w, S)
    base = (ul[sel] - w - x0[sel]).astype(np.float64)
    d, good, step = _row_gauss_newton(tables, base, d0[sel], iters, N, S - W)
    good &= (np.abs(step) < tol) & (np.abs(d - d0[sel]) <= max_change[sel])
    disp[sel] = np.where(good, d, d0[sel])
    ok[sel] = good
    return disp, ok


def _row_window_sums(left, right, ul, vl, x0, w, S):
    W = 2 * w + 1
    K = len(ul)
    wid = left.shape[1]
    dx = np.arange(-w, w + 1)
    rows = (vl[:, None] + dx[None, :])[:, :, None] * wid
    pl = np.take(np.ascontiguousarray(left).reshape(-1), rows + (ul[:, None] + dx[None, :])[:, None, :])
    pl = pl.astype(np.float32)
    pl -= pl.mean(axis=(1, 2), keepdims=True)
    ext = np.take(np.ascontiguousarray(right).reshape(-1), rows + (x0[:, None] + np.arange(-1, S + 1)[None, :])[:, None, :])
    ext = ext.astype(np.float32)
    st = ext[:, :, 1:-1]
    gr = 0.5 * (ext[:, :, 2:] - ext[:, :, :-2])
    col = np.zeros((7, K, S), np.float32)
    np.einsum("krc->kc", st, out=col[0])
    np.einsum("krc->kc", gr, out=col[1])
    np.einsum("krc,krc->kc", st, gr, out=col[2])
    np.einsum("krc,krc->kc", gr, gr, out=col[3])
    np.einsum("krc,krc->kc", st[:, :, :-1], gr[:, :, 1:], out=col[4, :, :-1])
    np.einsum("krc,krc->kc", st[:, :, 1:], gr[:, :, :-1], out=col[5, :, :-1])
    np.einsum("krc,krc->kc", gr[:, :, :-1], gr[:, :, 1:], out=col[6, :, :-1])
    col = col.astype(np.float64)
    win = np.empty((7, K, S - W + 1))
    win[:, :, 0] = col[:, :, :W].sum(axis=2)
    for j in range(1, S - W + 1):
        win[:, :, j] = win[:, :, j - 1] + col[:, :, j + W - 1] - col[:, :, j - 1]
    cross = np.matmul(pl.transpose(0, 2, 1), gr)
    cw = np.arange(W)[:, None]
    C = cross[:, cw, np.arange(S - W + 1)[None, :] + cw].sum(axis=1)
    return (*win, C)


def _row_gauss_newton(tables, base, d_init, iters, N, last_start):
    A, B, P00, Q00, P01, P10, Q01, C = tables
    K = len(d_init)
    kr = np.arange(K)
    d = d_init.copy()
    good = np.ones(K, bool)
    step = np.zeros(K)
    for _ in range(iters):
        pos = base - d
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
        hgg = s_gg - s_g * s_g / N
        flat = hgg <= 1e-6
        good &= ~flat
        srg = s_ig - s_i * s_g / N - s_lg
        step = np.clip(srg / np.where(flat, 1.0, hgg), -1.0, 1.0)
        d += np.where(flat, 0.0, step)
    return d, good, step


def _assert_identical(left, right, uv, d0, **kw):
    d, ok = refine_disparity_row(left, right, uv, d0, **kw)
    d_ref, ok_ref = _refine_reference(left, right, uv, d0, **kw)
    np.testing.assert_array_equal(ok, ok_ref)
    np.testing.assert_array_equal(d, d_ref)  # bit for bit (NaN where both are NaN)
    return ok


@pytest.mark.parametrize("disparity", [12.3, 30.85, 47.5])
@pytest.mark.parametrize("kw", [{}, {"half_window": 3, "iters": 3}, {"max_change": 1.5, "tol": 0.1}])
def test_refine_rows_identical_synthetic(gravel, shift_image, disparity, kw):
    """Shifted gravel texture, starts up to 2.5 px off, points up to the image borders (refused
    ones included) and NaN starts: the kernel reproduces the NumPy tables' result exactly."""
    rng = np.random.default_rng(7)
    right = shift_image(gravel, -disparity, 0.0)
    uv = np.column_stack([rng.uniform(0, 511, 400), rng.uniform(0, 511, 400)])
    d0 = disparity + rng.uniform(-2.5, 2.5, len(uv))
    d0[::37] = np.nan
    ok = _assert_identical(gravel, right, uv, d0, **kw)
    assert 0.4 < ok.mean() < 0.95  # converged points and refused ones (borders, NaN, far starts)


def test_refine_rows_identical_per_point_max_change(gravel, shift_image):
    rng = np.random.default_rng(3)
    right = shift_image(gravel, -20.4, 0.0)
    uv = np.column_stack([rng.uniform(40, 470, 300), rng.uniform(10, 500, 300)])
    d0 = 20.4 + rng.uniform(-3.0, 3.0, len(uv))
    ok = _assert_identical(gravel, right, uv, d0, max_change=rng.choice([1.0, 1.2, 2.4, 4.8], len(uv)))
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
    d_ref, ok_ref = _refine_reference(left, right, uv, d0)
    assert (ok == ok_ref).mean() > 0.99 and ok.mean() > 0.9
    np.testing.assert_allclose(d[ok & ok_ref], d_ref[ok & ok_ref], atol=1e-4)


def test_refine_rows_empty_and_registered():
    d, ok = refine_disparity_row(np.zeros((20, 40), np.uint8), np.zeros((20, 40), np.uint8), np.zeros((0, 2)), np.zeros(0))
    assert d.shape == (0,) and ok.shape == (0,)
    assert "vslam.features.stereo_kernels" in KERNEL_MODULES
    stereo_kernels.warm()


@pytest.mark.shared
def test_refine_rows_identical_kitti(shared_data):
    """KITTI 06 pairs, the project's keypoints and the tracker's LK starts (as ``stereo_by_flow``):
    identical disparities and flags, over a thousand refined points per frame."""
    seq = shared_data / "kitti_odometry/sequences/06"
    det = create_detector(FeatureConfig(n_features=2000))
    for i in (0, 30):
        left = cv2.imread(str(seq / f"image_0/{i:06d}.png"), cv2.IMREAD_GRAYSCALE)
        right = cv2.imread(str(seq / f"image_1/{i:06d}.png"), cv2.IMREAD_GRAYSCALE)
        uv = np.asarray(det.detect(left).uv, float)
        uvr, ok = klt_track(left, right, uv, init_uv=uv.copy(), window=11, levels=4, fb_threshold=0.0, max_iter=5,
                            eps=0.1)
        ok &= (np.abs(uvr[:, 1] - uv[:, 1]) < 1.5) & (uv[:, 0] - uvr[:, 0] > 707.0912 / 60.0)
        ok_row = _assert_identical(left, right, uv, np.where(ok, uv[:, 0] - uvr[:, 0], np.nan))
        assert ok_row.sum() > 900
