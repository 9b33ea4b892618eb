"""Timestamps: TUM association (vslam.trajectory.associate_timestamps, as the readers use it),
ground-truth interpolation."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from vslam.datasets.timestamps import interpolate_poses
from vslam.trajectory import Trajectory, associate_timestamps


def _associate_reference(first, second, offset, max_difference):
    """TUM associate.py, written out literally (all pairs, sort by |dt|, greedy)."""
    cands = sorted(
        (abs(a - (b + offset)), i, j)
        for i, a in enumerate(first) for j, b in enumerate(second) if abs(a - (b + offset)) < max_difference
    )
    used1, used2, out = set(), set(), []
    for _, i, j in cands:
        if i not in used1 and j not in used2:
            used1.add(i), used2.add(j), out.append((i, j))
    return sorted(out)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_associate_matches_reference(seed):
    rng = np.random.default_rng(seed)
    t1 = np.sort(rng.uniform(0, 10, 300))
    t2 = np.sort(rng.uniform(0, 10, 250))
    got = np.column_stack(associate_timestamps(t1, t2 + 0.003, 0.02))
    ref = _associate_reference(t1, t2, 0.003, 0.02)
    assert len(ref) > 50
    assert [tuple(p) for p in got] == ref


def test_associate_each_used_once():
    got = np.column_stack(associate_timestamps(np.array([0.0, 0.01]), np.array([0.005]), 0.02))
    assert got.tolist() == [[0, 0]]  # both are 5 ms away; the first candidate wins, used once
    assert len(associate_timestamps(np.array([0.0]), np.array([1.0]), 0.02)[0]) == 0


def test_interpolate_poses_slerp_and_gaps():
    rng = np.random.default_rng(3)
    tg = np.array([0.0, 0.01, 0.02, 0.5, 0.51])
    R = Rotation.from_rotvec(rng.normal(size=(5, 3)) * 0.3)
    T = np.tile(np.eye(4), (5, 1, 1))
    T[:, :3, :3] = R.as_matrix()
    T[:, :3, 3] = rng.normal(size=(5, 3))
    gt = Trajectory(tg, T)
    q = np.array([-0.1, 0.0, 0.004, 0.013, 0.3, 0.505, 0.6])
    Tq, valid = interpolate_poses(gt, q, max_gap=0.1)
    assert valid.tolist() == [False, True, True, True, False, True, False]
    np.testing.assert_allclose(Tq[1], T[0])
    a = 0.4
    np.testing.assert_allclose(Tq[2, :3, 3], (1 - a) * T[0, :3, 3] + a * T[1, :3, 3], atol=1e-12)
    ref = Slerp(tg, R)(q[[2, 3, 5]]).as_matrix()
    np.testing.assert_allclose(Tq[[2, 3, 5], :3, :3], ref, atol=1e-12)
    assert np.all(np.isnan(Tq[~valid]))
