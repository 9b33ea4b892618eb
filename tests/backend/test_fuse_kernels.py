"""The compiled kernels of neighbour fusion against the NumPy code of ``NeighbourFusion._fuse_into``
they replace (that code is kept here as the reference)."""
from __future__ import annotations

import numpy as np
import pytest

from vslam.backend import fuse_kernels


def _candidates_reference(pts, alive, point_ids, n_points):
    pts = pts[alive[pts]]
    observed = np.zeros(n_points + 1, dtype=bool)
    observed[point_ids] = True
    return pts[~observed[pts]]


def _fuse_reference(p, kp, zp, uv_m, kp_uv, sigma2, u0, u_right, bf, use_disp, chi2_mono, chi2_stereo,
                    point_ids, alive, n_obs, remap):
    """The NumPy code of ``_fuse_into`` from the chi-square test to the merge pairs."""
    chi2 = np.sum((uv_m - kp_uv[kp]) ** 2, axis=1) / sigma2
    thr = np.full(len(p), chi2_mono)
    if use_disp:
        disp = u0[kp] - u_right[kp]
        has = np.isfinite(disp)
        chi2 = chi2 + np.where(has, (np.where(has, disp, 0.0) - bf / zp) ** 2, 0.0) / sigma2
        thr = np.where(has, chi2_stereo, thr)
    ok = chi2 <= thr
    p, kp = p[ok], kp[ok]
    cur = point_ids[kp]
    free = (cur < 0) | ~alive[np.where(cur >= 0, cur, 0)]
    point_ids[kp[free]] = p[free]
    np.add.at(n_obs, p[free], 1)
    dup = ~free & (cur != p)
    a, b = remap[p[dup]], remap[cur[dup]]
    keep_a = n_obs[a] >= n_obs[b]
    return np.where(keep_a, b, a), np.where(keep_a, a, b)


def test_candidate_points_is_the_numpy_filter():
    fuse_kernels.warm()
    rng = np.random.default_rng(3)
    n = 5000
    alive = rng.random(n + 7) < 0.7  # (a store's arrays are longer than its rows)
    for _ in range(5):
        pts = np.sort(rng.choice(n, 1500, replace=False)).astype(np.int64)
        point_ids = rng.integers(-1, n, 2000)
        point_ids[rng.random(2000) < 0.3] = -1
        got = fuse_kernels.candidate_points(pts, alive, point_ids, n)
        want = _candidates_reference(pts, alive, point_ids, n)
        assert got.dtype == np.int64 and np.array_equal(got, want)
        assert 300 < len(got) < 1400  # both filters removed points


@pytest.mark.parametrize("use_disp", [False, True])
def test_fuse_matches_is_the_numpy_code_to_the_bit(use_disp):
    rng = np.random.default_rng(11 + use_disp)
    n_pts, n_kp, m = 4000, 1500, 900
    for trial in range(4):
        alive = rng.random(n_pts) < 0.8
        n_obs = rng.integers(1, 6, n_pts).astype(np.int32)
        remap = np.arange(n_pts + 1, dtype=np.int64)
        remap[-1] = -1
        fused = rng.choice(n_pts, 50, replace=False)  # some points merged earlier in the pass
        remap[fused] = rng.integers(0, n_pts, 50)
        point_ids = rng.integers(-1, n_pts, n_kp)
        point_ids[rng.random(n_kp) < 0.4] = -1
        kp = rng.choice(n_kp, m, replace=False).astype(np.int64)  # unique keypoints, as guided_match gives
        p = rng.choice(n_pts, m, replace=False).astype(np.int64)
        p[:20] = point_ids[kp[:20]]  # a few matches to the keypoint's own point
        kp_uv = rng.uniform(0, 640, (n_kp, 2))
        uv_m = kp_uv[kp] + rng.normal(scale=1.5, size=(m, 2))
        octave = rng.integers(0, 8, m)
        sigma2 = np.power(1.2, 2.0 * octave.astype(float))
        zp = rng.uniform(0.5, 5.0, m)
        bf = 40.0
        u0 = rng.uniform(0, 640, n_kp)
        u_right = u0 - bf / rng.uniform(0.5, 5.0, n_kp)
        u_right[rng.random(n_kp) < 0.3] = np.nan
        args = (p, kp, zp, uv_m, kp_uv, sigma2, u0, u_right, bf, use_disp, 5.991, 7.815)
        pid_ref, nobs_ref = point_ids.copy(), n_obs.copy()
        want = _fuse_reference(*args, pid_ref, alive, nobs_ref, remap)
        got = fuse_kernels.fuse_matches(*args, point_ids, alive, n_obs, remap)
        for g, w in zip(got, want, strict=True):
            assert g.dtype == np.int64 and np.array_equal(g, w)
        assert np.array_equal(point_ids, pid_ref) and np.array_equal(n_obs, nobs_ref)
        assert len(got[0]) > 50  # merge pairs
        assert 100 < np.count_nonzero(point_ids[kp] == p) < m  # new observations, some matches rejected
