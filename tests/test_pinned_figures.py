"""Every sensor on every shared sequence, pinned from both sides in bands that hold across machines.

One run per row, as ``vslam bench benchmarks/all.yaml`` runs it (:func:`vslam.api.run_path`,
default configuration), plus issue 7's global localization on 7-Scenes (map of frames 0-599, cold
start on 600-999). A change that moves any row outside its band fails here, whatever README shows:
an ATE that gets worse *or* better, frames that stop being tracked, a loop that closes with other
keyframes or another inlier count.

How the bands were set (issue 29): every row was run under four CPU profiles of this machine (an
AMD EPYC with AVX-512): the default (OpenBLAS picks its SkylakeX kernels), ``OPENBLAS_CORETYPE=Haswell``,
``OPENBLAS_CORETYPE=SandyBridge NUMBA_CPU_NAME=generic OMP_NUM_THREADS=1`` (another BLAS kernel and
numba code without AVX2/FMA) and ``OPENBLAS_CORETYPE=Prescott OMP_NUM_THREADS=1
OPENBLAS_NUM_THREADS=1``. ``SPREAD`` below is the range seen over those runs (2026-11-27); each band
is that range widened by ``MARGIN`` (3 % of the value each side) and, for the rows whose spread
shows they react to rounding (the localization, where the profiles differ by two frames and 8 % of
ATE), by the spread once more. Counts get an absolute slack of a few frames where they moved, none
where every profile agreed and a single frame more would mean another trajectory.
"""
from __future__ import annotations

from dataclasses import dataclass

import pytest

from vslam.api import run_path

pytestmark = pytest.mark.shared

MARGIN = 0.03  # relative, each side of the measured spread


@dataclass(frozen=True)
class Pin:
    folder: str
    sensor: str
    frames: int
    spread: tuple[float, float]  # ATE RMSE [m] over the four profiles (min, max)
    scale: tuple[float, float] | None = None  # monocular Sim(3) scale over the profiles
    loops: tuple[tuple[int, int, int], ...] = ()  # (query frame, matched frame, inliers) as measured
    min_tracked: int | None = None  # default: every frame

    def ate_band(self) -> tuple[float, float]:
        lo, hi = self.spread
        return lo * (1 - MARGIN) - (hi - lo), hi * (1 + MARGIN) + (hi - lo)


# Measured values (default profile) in the comments; SPREAD over the four profiles.
PINS = {
    # 0.043093; loop keyframe 938 -> 241, 187 inliers (before the sub-pixel keypoints of stereo and RGB-D,
    # issue 24: 0.043255, 937 -> 248 with 162)
    "7scenes-redkitchen-rgbd": Pin("7scenes_redkitchen", "rgbd", 1000, (0.043093, 0.043093), loops=((938, 241, 187),)),
    # 0.033937, scale 2.0914 (2.09140 under SandyBridge + generic numba), no loop: with the wider
    # monocular local map of issue 24 round 8 the return to the start is tracked against its old
    # keyframes instead of closed as a loop. Before: 0.044825, scale 1.9484, loop 944 -> 251 with 287
    # inliers. Start frames 3, 7, 12, 20 give 0.0330-0.0371 (0.0360-0.0413 before; benchmarks/RESULTS.md):
    # a monocular run's ATE is that sensitive to its start.
    "7scenes-redkitchen-mono": Pin("7scenes_redkitchen", "mono", 1000, (0.033937, 0.033937), scale=(2.09140, 2.09141)),
    # 0.0027953 on every profile, with the depth weight of a registered RGB-D sensor (issue 24 round 6;
    # 0.0040595 before, 0.0041296 before the sub-pixel keypoints)
    "tum-fr1-desk-9-rgbd": Pin("tum_rgbd_freiburg1_desk_9frames", "rgbd", 9, (0.0027953, 0.0027953)),
    # 0.046328 (0.050001 before the sub-pixel keypoints)
    "kitti06-stereo": Pin("kitti_odometry/sequences/06", "stereo", 51, (0.046328, 0.046328)),
    # 0.326273, scale 9.92826 (9.92819 under the three other profiles)
    "kitti07-mono": Pin("kitti_odometry/sequences/07", "mono", 160, (0.326273, 0.326273), scale=(9.92819, 9.92826)),
    "euroc-v101-40-stereo": Pin("euroc_V1_01_easy_40frames", "stereo", 40, (0.00068965, 0.00068965)),  # 0.00069020
    # EuRoC MH_01, 80 frames of hand-held motion (issue 28's clip)
    "euroc-mh01-80-stereo": Pin("euroc_mh01_vi_80", "stereo", 80, (0.0029703, 0.0029704)),  # 0.0031717 before
    "euroc-mh01-80-mono": Pin("euroc_mh01_vi_80", "mono", 80, (0.0026029, 0.0026029), scale=(0.58613, 0.58613)),
}
LOOP_FRAMES = 3  # a loop's query / matched frame may move this many frames
LOOP_INLIERS = 0.15  # and its inlier count this share (an unrefined loop's count is off by 70 %)


def _in(value: float, band: tuple[float, float]) -> bool:
    return band[0] <= value <= band[1]


def _check_loops(got: list, pinned: tuple[tuple[int, int, int], ...]) -> None:
    assert len(got) == len(pinned), (got, pinned)
    for (q, m, n), (q0, m0, n0) in zip(got, pinned):
        assert abs(q - q0) <= LOOP_FRAMES and abs(m - m0) <= LOOP_FRAMES, (got, pinned)
        assert abs(n - n0) <= LOOP_INLIERS * n0, (got, pinned)


@pytest.fixture(scope="module", params=sorted(PINS))
def pinned_row(request, shared_data, tmp_path_factory):
    name = request.param
    pin = PINS[name]
    out = tmp_path_factory.mktemp(name)
    result = run_path(shared_data / pin.folder, out, sensor=pin.sensor, prefetch="none")
    return name, result.stats


def test_pinned_row(pinned_row):
    name, stats = pinned_row
    pin = PINS[name]
    min_tracked = pin.frames if pin.min_tracked is None else pin.min_tracked
    assert stats["frames"] == pin.frames and stats["tracked"] >= min_tracked, stats
    assert stats["matched_poses"] == stats["tracked"]
    if pin.scale is not None:  # Sim(3) alignment: the monocular map's scale, pinned too
        lo, hi = pin.scale
        assert _in(stats["scale"], (lo * (1 - MARGIN), hi * (1 + MARGIN))), stats["scale"]
    else:  # depth sensors are evaluated with SE(3) (no scale absorbs part of the error)
        assert stats["scale"] == 1.0
    assert _in(stats["ate_rmse"], pin.ate_band()), (name, stats["ate_rmse"], pin.ate_band())
    _check_loops(stats["loops"], pin.loops)


def test_readme_cabinet_row(cabinet_run):
    """README row tum-fr3-cabinet-kf58-rgbd (the session's cabinet run, tests/conftest.py): all 58
    frames, ATE 0.026722 on every profile, one loop (frame 54 -> 53, 19 inliers), with the depth
    weight of a registered RGB-D sensor (issue 24 round 6). Before it: 0.029378 and no loop; before
    the sub-pixel keypoints of stereo and RGB-D 0.032233 with one loop, keyframe 57 -> 2 on 10
    refined inliers (ORB-SLAM3 keeps 2 poses of this sequence)."""
    from vslam.eval.evaluate import evaluate_trajectories

    ds, system, results = cabinet_run
    assert sum(r.T_world_cam is not None for r in results) == 58
    res = evaluate_trajectories(system.trajectory(), ds.ground_truth())
    assert res.matched_poses == 58
    assert _in(res.ate.rmse, Pin("", "rgbd", 58, (0.026722, 0.026722)).ate_band()), res.ate.rmse
    _check_loops(system.stats()["loops"], ((54, 53, 19),))


@pytest.fixture(scope="module")
def sevenscenes_localization(shared_data, tmp_path_factory):
    """Issue 7: a map of 7-Scenes frames 0-599 (``vslam run --max-frames 600``), then global
    localization from a cold start on frames 600-999 (``vslam localize --start-frame 600``)."""
    from vslam.localize import localize_path

    root = tmp_path_factory.mktemp("7scenes_loc")
    data = shared_data / "7scenes_redkitchen"
    run_path(data, root / "map", sensor="rgbd", max_frames=600, prefetch="none")
    return localize_path(root / "map", data, root / "loc", start_frame=600, max_frames=400).stats


# Localization of 7-Scenes 600-999 in the map of 0-599 over the profiles (sub-pixel keypoints, issue
# 24): localized 396 / 396 / 397 / 371 (tracked 386 / 385 / 384 / 359, relocalized 10 / 11 / 13 / 12),
# ATE 0.04457 / 0.04979 / 0.04346 / 0.04443 m under the default / Haswell / SandyBridge + generic numba
# / Prescott profiles. Its counts react to rounding: one pose that PnP accepts or not changes what
# follows (under Prescott a stretch of 25 frames more is lost). Before: 367-369 localized, 0.04570-0.04946.
LOC_LOCALIZED = (369, 399)  # measured 371-397, +-2 frames
LOC_ATE = Pin("", "rgbd", 400, (0.04346, 0.04979)).ate_band()


def test_7scenes_localization(sevenscenes_localization):
    """History of the default profile's figures: 396/400 (386 tracked, 10 relocalized, 4 lost),
    ATE 0.04457 m with the sub-pixel keypoints of issue 24; 368/400 (354 tracked, 14 relocalized, 32 lost),
    ATE 0.04946 m; 367/400, 0.04961 before solve_pnp's LM became our own compiled one; 369/400,
    0.04550 before pose refinement stepped with ``lie.so3_exp``; 366/400, 0.04530 before issue 15's
    per-point Schur sums; 386/400, 0.047 when issue 7 closed. Issue 16 asks for >= 360 and < 0.05.
    Disabling the implausible-step check (``localize.max_step_m=1000``, ``max_step_deg=180``) sends
    the ATE and the relocalizations out of their bands (measured 0.0658 m, 4 relocalizations, 372
    localized; before issue 24's keypoints 0.0662 m, 8, 372)."""
    s = sevenscenes_localization
    assert s["frames"] == 400
    assert _in(s["localized"], LOC_LOCALIZED), s
    assert s["localized"] == s["tracked"] + s["relocalizations"] and s["lost"] == 400 - s["localized"], s
    assert 8 <= s["relocalizations"] <= 15, s  # 10-13
    assert s["localized"] >= 360  # issue 16's goal; its ATE < 0.05 held on every profile (max 0.04979)
    assert _in(s["ate_rmse"], LOC_ATE), (s["ate_rmse"], LOC_ATE)
    assert s["matched_poses"] == s["localized"]
