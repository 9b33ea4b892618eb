"""Rectified stereo: the row-constrained disparity refinement on exactly known disparities, and
depth from disparity."""
from __future__ import annotations

import numpy as np
import pytest

from vslam.features import stereo_depth
from vslam.features.stereo import refine_disparity_row

FX, BASELINE = 707.0912, 0.53716


@pytest.mark.parametrize("base", [12, 47])
def test_refine_disparity_row_unbiased(gravel, shift_image, base):
    """Row-constrained LK recovers exactly known disparities from starts up to 2.5 px off. Linear
    interpolation leaves a small error that depends on the sub-pixel part (pixel locking, odd
    about integers and half-integers); over the sub-pixel parts it averages out: no bias in depth
    (mean error < 0.1 % of the disparity)."""
    rng = np.random.default_rng(4)
    uv = np.column_stack([rng.uniform(80, 430, 300), rng.uniform(20, 490, 300)])
    errs = []
    for frac in np.arange(0.05, 1.0, 0.1):
        disparity = base + frac
        right = shift_image(gravel, -disparity, 0.0)
        d0 = disparity + rng.uniform(-2.5, 2.5, len(uv))
        d, ok = refine_disparity_row(gravel, right, uv, d0)
        assert ok.mean() > 0.95
        err = d[ok] - disparity
        assert np.median(np.abs(err)) < 0.04
        errs.append(np.median(err))
    assert np.abs(np.mean(errs)) < 1e-3 * base
    # NaN starts are skipped; windows leaving the image are refused, not clipped
    d, ok = refine_disparity_row(gravel, right, np.array([[200.0, 100.0], [3.0, 100.0], [20.0, 100.0]]),
                                 np.array([np.nan, 10.0, 30.0]))
    assert not ok.any() and np.isnan(d[0])


def test_stereo_depth():
    z = stereo_depth(np.array([110.0, 50.0]), np.array([100.0, 50.0]), FX, BASELINE)
    assert z[0] == pytest.approx(FX * BASELINE / 10.0) and np.isinf(z[1])
