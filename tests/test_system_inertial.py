"""The inertial sensors end to end on REAL EuRoC MH_01 (hand-held excitation, 80 frames, 4 s, 200 Hz
IMU): ``run_path(sensor="mono-inertial" | "stereo-inertial")`` against EuRoC's ground truth (its
world is z up), beside the plain ``stereo`` run of the same frames.

Measured on this machine (deterministic backend; the same numbers every run and under three CPU
profiles). Since the visual-inertial local BA, the full VI-BA after the initialization and the
tracker's inertial pose optimization (#28 items 4-6; before them: mono-inertial 0.0030 m, scale
1.0035; stereo-inertial 0.0033 m, scale 1.0086), and the final full VI-BA (before it:
mono-inertial 0.0028 m, 1.0037, 0.29 deg; stereo-inertial 0.0029 m, 1.0057, 0.18 deg; and before
the wider monocular local map of #24 round 8: mono-inertial 0.0028 m, 1.0029, 0.24 deg):

| run | SE(3) ATE | Sim(3) scale | world z vs gravity | IMU initialized |
|---|---|---|---|---|
| mono-inertial | 0.0026 m | 1.0019 | 0.36 deg | frame 40, 2.00 s |
| stereo-inertial | 0.0027 m | 1.0039 | 0.32 deg | frame 25, 1.25 s |
| stereo | 0.0032 m | | (visual world: first camera) | |

The bounds below sit a little above these (for other CPUs' rounding), inside the issue's goals
(#28: mono-inertial SE(3) ATE <= 0.02 m, scale within 5 %, initialized within ~2 s of motion;
stereo-inertial no worse than stereo, world z within 2 degrees of gravity).
"""
from __future__ import annotations

import numpy as np
import pytest

from vslam.eval.evaluate import evaluate_trajectories
from vslam.map.io import load_map

MH01 = "euroc_mh01_vi_80"


@pytest.fixture(scope="module")
def runs(shared_data, tmp_path_factory):
    """``{sensor: RunResult}`` for mono-inertial, stereo-inertial and stereo on MH_01."""
    from vslam.api import run_path

    out = {}
    for sensor in ("mono-inertial", "stereo-inertial", "stereo"):
        folder = tmp_path_factory.mktemp(sensor)
        out[sensor] = run_path(shared_data / MH01, folder / "run", sensor=sensor, prefetch="none")
    return out


def gravity_tilt_deg(result, gt) -> float:
    """Angle between the run's world z axis and the ground truth's (up; EuRoC's world is z up),
    through the SE(3) alignment of the trajectory onto the ground truth."""
    R = evaluate_trajectories(result.trajectory, gt, align="se3").alignment.R
    return float(np.degrees(np.arccos(np.clip(R[2, 2], -1.0, 1.0))))


@pytest.fixture(scope="module")
def gt(shared_data):
    from vslam.datasets import open_dataset

    return open_dataset(shared_data / MH01, sensor="stereo").ground_truth()


@pytest.mark.shared
def test_mono_inertial_is_metric_and_gravity_aligned(runs, gt):
    r = runs["mono-inertial"]
    s = r.stats
    assert len(r.trajectory) == s["frames"] == 80                # a pose for every frame
    assert s["sensor"] == "mono-inertial" and s["imu_initialized"]
    assert s["imu_init_time_s"] <= 2.5 and s["imu_init_frame"] <= 50
    assert 0.1 < s["imu_scale"] < 10 and s["gravity"] == [0.0, 0.0, -9.81]
    assert len(s["imu_bias_gyro"]) == len(s["imu_bias_accel"]) == 3
    assert s["imu_predicted_frames"] >= 80 - s["imu_init_frame"] - 1   # the IMU predicted every later frame
    se3 = evaluate_trajectories(r.trajectory, gt, align="se3")
    sim3 = evaluate_trajectories(r.trajectory, gt, align="sim3")
    assert se3.ate_rmse <= 0.005                                  # measured 0.0026 (goal 0.02)
    assert s["ate_rmse"] == pytest.approx(se3.ate_rmse)           # the run evaluated it SE(3) (metric)
    assert abs(sim3.scale - 1.0) <= 0.02                          # measured 1.0019 (goal 5 %)
    assert gravity_tilt_deg(r, gt) <= 1.0                         # measured 0.36 (0.43 before VI-BA)


@pytest.mark.shared
def test_stereo_inertial_is_gravity_aligned_and_as_good_as_stereo(runs, gt):
    r, plain = runs["stereo-inertial"], runs["stereo"]
    s = r.stats
    assert len(r.trajectory) == 80 and s["imu_initialized"] and "imu_scale" not in s
    assert s["imu_init_time_s"] <= 1.5                            # measured 1.25 (10 keyframes after 1 s)
    assert gravity_tilt_deg(r, gt) <= 1.0                         # measured 0.18 (goal 2)
    # measured 0.00288 vs 0.00317 (0.0033 before VI-BA) with features.subpixel=off, 0.00300 vs 0.00297
    # with parabola (frontend.keyframes.tracked_ratio_inertial: the figures of its other values beside it)
    assert s["ate_rmse"] <= plain.stats["ate_rmse"] + 0.0001
    assert "imu_initialized" not in plain.stats                   # plain sensors report no IMU


def test_inertial_sensor_needs_the_imu():
    """``System`` with an inertial sensor and no IMU: one error naming what is missing."""
    from vslam.errors import DatasetError
    from vslam.geometry.camera import PinholeCamera
    from vslam.system import System

    cam = PinholeCamera(500.0, 500.0, 320.0, 240.0, 640, 480)
    with pytest.raises(DatasetError, match="mono-inertial needs IMU samples and IMU calibration"):
        System(None, cam, sensor="mono-inertial")
    assert System(None, cam, sensor="mono").inertial is None


def gt_velocity(shared_data, t: np.ndarray) -> np.ndarray:
    """The IMU (body) velocity of EuRoC's ground truth at ``t``: central differences of its 200 Hz
    positions (``state_groundtruth_estimate0``; the body is the IMU, ``T_BS`` identity), interpolated."""
    raw = np.loadtxt(shared_data / MH01 / "mav0" / "state_groundtruth_estimate0" / "data.csv", delimiter=",",
                     comments="#")
    tg, p = raw[:, 0] * 1e-9, raw[:, 1:4]
    v = np.gradient(p, tg, axis=0)
    return np.column_stack([np.interp(t, tg, v[:, k]) for k in range(3)])


@pytest.mark.shared
@pytest.mark.parametrize("sensor", ["mono-inertial", "stereo-inertial"])
def test_velocities_and_biases_are_estimated(runs, gt, shared_data, sensor):
    """``imu_states.csv``: each frame's velocity from the tracker's inertial pose optimization (not
    from differences of tracked poses) against the ground truth's (differentiated, rotated into the
    run's world by the SE(3) alignment). Measured RMS / max error: mono-inertial 0.020 / 0.032 m/s,
    stereo-inertial 0.019 / 0.035 m/s (speeds ~0.6 m/s); the finite differences used before gave
    0.034 / 0.087 and 0.022 / 0.065: bands 0.025 / 0.05. The biases move (VI-BA, tracking) and
    ``stats.json`` reports the last estimate beside the initialization's; the gyro bias stays within
    5 mrad/s of the ground truth's (-0.0032, 0.0213, 0.0785): measured <= 0.9 mrad/s (mono) and
    0.7 (stereo) after the final full VI-BA (2.2 and 1.0 before it)."""
    from vslam.inertial.states_csv import read_imu_states

    r = runs[sensor]
    s = r.stats
    R = evaluate_trajectories(r.trajectory, gt, align="se3").alignment.R
    st = read_imu_states(r.output_dir / "imu_states.csv")
    v = np.column_stack([st["vx"], st["vy"], st["vz"]]) @ R.T
    e = np.linalg.norm(v - gt_velocity(shared_data, st["timestamp"]), axis=1)
    assert np.sqrt(np.mean(e**2)) <= 0.025 and e.max() <= 0.05
    bias = np.column_stack([st[c] for c in ("bgx", "bgy", "bgz", "bax", "bay", "baz")])
    assert np.all(bias.std(axis=0) > 0)                           # the biases move
    assert s["imu_bias_gyro"] != s["imu_init_bias_gyro"] and s["imu_full_ba"] >= 1
    # the last estimate: the final full VI-BA's (backend.final_inertial_ba), after the last frame's row
    m, *_ = load_map(r.output_dir)
    newest = max((k for k in m.keyframes.values() if "imu_bias" in k.extra), key=lambda k: k.timestamp)
    np.testing.assert_allclose(s["imu_bias_gyro"], newest.extra["imu_bias"][:3], atol=1e-9)
    assert np.abs(np.array(s["imu_bias_gyro"]) - [-0.003172, 0.021268, 0.078502]).max() < 0.005
    # every local BA after the initialization is visual-inertial: measured 2 (mono: keyframes 14, 15
    # come after frame 40) and 23 (stereo; 21 with features.subpixel=parabola)
    assert s["backend"]["vi_ba_calls"] >= (2 if sensor == "mono-inertial" else 15)
    assert len(s["backend"]["vi_ba_full"]) == s["imu_full_ba"]


@pytest.mark.shared
def test_keyframe_states_contract(shared_data):
    """The state every keyframe carries once the IMU is initialized (the contract map saving and
    merging rely on): ``extra["imu_velocity"]`` (3,) float64 (world, m/s) and ``extra["imu_bias"]``
    (6,) float64 (gyro, then accelerometer), on every keyframe of the initialization's window and
    after; none before it is tried on a map that is not gravity-aligned yet."""
    from vslam.api import _open_run, resolve_config
    from vslam.system import System

    ds, sensor, stop, imu_inputs = _open_run(shared_data / MH01, None, "stereo-inertial", None, None, False, 0, None,
                                             None, None)
    system = System(resolve_config(None, []), ds.camera, sensor=sensor, **imu_inputs)
    assert system.map.gravity_aligned is False
    for i, frame in enumerate(ds):
        system.track(frame)
        if i == 20:                                               # before the initialization (frame 25)
            assert not any("imu_velocity" in k.extra for k in system.map.keyframes.values())
    system.finish()
    assert system.map.gravity_aligned is True
    kfs = [k for k in system.map.keyframes.values() if not k.bad]
    for kf in kfs:
        v, b = kf.extra["imu_velocity"], kf.extra["imu_bias"]
        assert v.shape == (3,) and b.shape == (6,) and v.dtype == b.dtype == np.float64
        assert 0.0 < np.linalg.norm(v) < 2.0 and np.abs(b[:3]).max() < 0.2 and np.abs(b[3:]).max() < 1.0


@pytest.mark.shared
def test_full_vi_ba_again_a_few_seconds_later(shared_data, gt, tmp_path, monkeypatch):
    """The full VI-BA runs right after the initialization and again at ``REFINE_AT_S`` from the first
    keyframe (ORB-SLAM3: 5 s and 15 s, past this 4 s clip; moved to 3 s here): two full VI-BAs, the
    biases re-estimated by the second (gyro bias within 5 mrad/s of the ground truth's, measured 0.7),
    and the ATE as good (measured stereo-inertial 0.00282 m with it, 0.00288 without: band 0.0035)."""
    import vslam.backend.inertial_mapping as inertial_mapping
    from vslam.api import run_path

    monkeypatch.setattr(inertial_mapping, "REFINE_AT_S", (3.0,))
    r = run_path(shared_data / MH01, tmp_path / "run", sensor="stereo-inertial", prefetch="none",
                 overrides=["backend.final_inertial_ba=false"])  # the schedule alone (the end's is tested below)
    s = r.stats
    assert s["imu_full_ba"] == 2 and len(s["backend"]["vi_ba_full"]) == 2
    first, second = s["backend"]["vi_ba_full"]
    assert second["keyframes"] > first["keyframes"]               # the map grew in between
    assert np.abs(np.array(s["imu_bias_gyro"]) - [-0.003172, 0.021268, 0.078502]).max() < 0.005
    assert evaluate_trajectories(r.trajectory, gt, align="se3").ate_rmse <= 0.0035


@pytest.mark.shared
def test_a_final_full_vi_ba_ends_the_run(runs, shared_data, gt, tmp_path):
    """``backend.final_inertial_ba`` (on by default): one more full VI-BA over the segment once the
    input ends, after the one of the initialization (this clip is shorter than the first refinement
    at 5 s). Measured on MH_01 (three CPU profiles, the same figures): stereo-inertial SE(3) ATE
    0.00272 m with it, 0.00288 without (ORB-SLAM3 stereo-inertial 0.0028-0.0029 in the bench runs);
    mono-inertial 0.00279 / 0.00280. Bands: it must not make stereo-inertial worse, and stays below 0.0031."""
    from vslam.api import run_path

    s = runs["stereo-inertial"].stats
    assert s["imu_full_ba"] == 2 and len(s["backend"]["vi_ba_full"]) == 2
    first, last = s["backend"]["vi_ba_full"]
    assert last["keyframes"] > first["keyframes"]                   # the whole segment at the end
    off = run_path(shared_data / MH01, tmp_path / "off", sensor="stereo-inertial", prefetch="none",
                   overrides=["backend.final_inertial_ba=false"]).stats
    assert off["imu_full_ba"] == 1
    assert s["ate_rmse"] <= off["ate_rmse"] + 1e-5 and s["ate_rmse"] < 0.0031
