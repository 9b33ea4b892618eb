"""A synthetic IMU on the synthetic camera path: angular velocity and specific force in the IMU
frame from the exact, analytic trajectory (:func:`vslam.datasets.synthetic.trajectory.path_at`),
with EuRoC-like white noise and bias random walk (seeded), and the exact ground truth.

Model (the Kalibr / EuRoC IMU noise model, discrete at ``dt = 1 / rate``)::

    w_k = w_true(t_k) + b_g,k + n_g,k,   n_g ~ N(0, sigma_g^2 / dt)
    a_k = R_world_imu(t_k)^T (p_ddot(t_k) - g_world) + b_a,k + n_a,k,   n_a ~ N(0, sigma_a^2 / dt)
    b_k+1 = b_k + N(0, sigma_b^2 dt)

with ``g_world = (0, 0, -g)`` (the synthetic world is z up). ``w_true = vee(R^T dR/dt)`` and
``p_ddot`` come from 5-point central differences of the analytic path with a step of 2e-4 of one
lap's duration: truncation (``h^4 f^(5)/30``, ``h^4 f^(6)/90``) and round-off (``~eps |p| / h^2``)
both stay below 1e-8 (rad/s, m/s^2) for the default paths, far below any noise or integration error
tested against them.

The IMU frame (default :data:`T_CAM_IMU`): x forward (camera z), y left (camera -x), z up (camera
-y), 5 cm / 2 cm / 3 cm from the camera centre, so the specific force has lever-arm terms.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from vslam.datasets.synthetic.sequence import SyntheticConfig
from vslam.datasets.synthetic.trajectory import path_at
from vslam.errors import ConfigError, DatasetError
from vslam.inertial import DEFAULT_NOISE, ImuCalibration, ImuMeasurements

#: IMU -> camera of the synthetic rig (IMU axes x forward, y left, z up; lever arm in metres).
T_CAM_IMU = np.array([
    [0.0, -1.0, 0.0, 0.05],
    [0.0, 0.0, -1.0, 0.02],
    [1.0, 0.0, 0.0, -0.03],
    [0.0, 0.0, 0.0, 1.0],
])


@dataclass(frozen=True)
class SyntheticImuConfig:
    """The synthetic IMU.

    Attributes:
        rate_hz: sample rate (EuRoC: 200).
        lead_s: the IMU starts this long before the first frame (EuRoC MH_01 clip: 2 s).
        noise: False gives exact samples (no white noise, constant biases at their initial values).
        gyro_noise_density, gyro_random_walk, accel_noise_density, accel_random_walk: the noise
            model (defaults: EuRoC's ADIS16448).
        gyro_bias, accel_bias: initial biases (rad/s, m/s^2), of EuRoC's order.
        gravity: m/s^2. seed: seeds all noise. T_cam_imu: 16 numbers, IMU -> camera.
    """

    rate_hz: float = 200.0
    lead_s: float = 1.0
    noise: bool = True
    gyro_noise_density: float = DEFAULT_NOISE["gyro_noise_density"]
    gyro_random_walk: float = DEFAULT_NOISE["gyro_random_walk"]
    accel_noise_density: float = DEFAULT_NOISE["accel_noise_density"]
    accel_random_walk: float = DEFAULT_NOISE["accel_random_walk"]
    gyro_bias: tuple[float, float, float] = (-0.002, 0.021, 0.076)
    accel_bias: tuple[float, float, float] = (-0.025, 0.137, 0.076)
    gravity: float = 9.81
    seed: int = 0
    T_cam_imu: tuple[float, ...] = field(default=tuple(T_CAM_IMU.ravel()))

    def __post_init__(self) -> None:
        if not self.rate_hz > 0 or self.lead_s < 0:
            raise ConfigError(f"synthetic IMU: rate_hz must be > 0 and lead_s >= 0, got {self.rate_hz}, {self.lead_s}")

    def calibration(self) -> ImuCalibration:
        """The exact calibration (``T_imu_cam``, noise, rate) of this IMU."""
        T_imu_cam = np.linalg.inv(np.asarray(self.T_cam_imu, float).reshape(4, 4))
        return ImuCalibration(T_imu_cam, self.gyro_noise_density, self.gyro_random_walk, self.accel_noise_density,
                              self.accel_random_walk, self.rate_hz, 0.0, self.gravity, source="synthetic")


@dataclass(frozen=True)
class SyntheticImu:
    """Samples and exact ground truth at the sample times ``(N,)`` (IMU frame; world z up).

    ``timestamps`` (s, from integer ns), ``gyro``/``accel`` (measured), ``gyro_true``/``accel_true``
    (noise- and bias-free), ``T_world_imu (N, 4, 4)``, ``v_world (N, 3)``, ``gyro_bias``/``accel_bias``
    ``(N, 3)`` (the biases inside each sample).
    """

    timestamps_ns: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray
    gyro_true: np.ndarray
    accel_true: np.ndarray
    T_world_imu: np.ndarray
    v_world: np.ndarray
    gyro_bias: np.ndarray
    accel_bias: np.ndarray

    @property
    def timestamps(self) -> np.ndarray:
        return self.timestamps_ns * 1e-9

    def measurements(self, source: str = "synthetic") -> ImuMeasurements:
        return ImuMeasurements(self.timestamps, self.gyro, self.accel, source)


def _stencil_d1(f, t: np.ndarray, h: float) -> np.ndarray:
    return (f(t - 2 * h) - 8 * f(t - h) + 8 * f(t + h) - f(t + 2 * h)) / (12 * h)


def _stencil_d2(f, t: np.ndarray, h: float) -> np.ndarray:
    return (-f(t - 2 * h) + 16 * f(t - h) - 30 * f(t) + 16 * f(t + h) - f(t + 2 * h)) / (12 * h * h)


def imu_motion(config: SyntheticConfig, t: np.ndarray, T_cam_imu: np.ndarray, gravity: float = 9.81):
    """Exact ``(T_world_imu, v_world, w_imu, f_imu)`` of the IMU at times ``t (N,)`` on ``config``'s
    path: pose, velocity, angular velocity and specific force (module docstring)."""
    t = np.asarray(t, dtype=float)
    n = config.n_frames
    lap_s = max(n - 1, 1) / config.fps / (config.laps if config.path == "loop" else 1.0)
    h = 2e-4 * lap_s

    def T_world_imu(tt: np.ndarray) -> np.ndarray:
        return path_at(config.path, (tt - config.start_time) * config.fps, n, config.laps) @ T_cam_imu

    T = T_world_imu(t)
    R = T[:, :3, :3]
    R_dot = _stencil_d1(lambda tt: T_world_imu(tt)[:, :3, :3], t, h)
    v = _stencil_d1(lambda tt: T_world_imu(tt)[:, :3, 3], t, h)
    acc = _stencil_d2(lambda tt: T_world_imu(tt)[:, :3, 3], t, h)
    W = np.transpose(R, (0, 2, 1)) @ R_dot
    W = 0.5 * (W - np.transpose(W, (0, 2, 1)))
    w = np.stack([W[:, 2, 1], W[:, 0, 2], W[:, 1, 0]], axis=1)
    g_world = np.array([0.0, 0.0, -gravity])
    f = np.einsum("nji,nj->ni", R, acc - g_world)
    return T, v, w, f


def simulate_imu(config: SyntheticConfig, imu: SyntheticImuConfig = SyntheticImuConfig()) -> SyntheticImu:
    """Samples at ``rate_hz`` from ``start_time - lead_s`` to the last frame (inclusive when it
    falls on the grid), on integer-nanosecond stamps, with noise per ``imu`` (seeded)."""
    period_ns = int(round(1e9 / imu.rate_hz))
    t0_ns = int(round((config.start_time - imu.lead_s) * 1e9))
    t_end_ns = int(round(float(config.timestamps()[-1]) * 1e9))
    ns = np.arange(t0_ns, t_end_ns + 1, period_ns, dtype=np.int64)
    T_cam_imu = np.asarray(imu.T_cam_imu, float).reshape(4, 4)
    T, v, w, f = imu_motion(config, ns * 1e-9, T_cam_imu, imu.gravity)
    n, dt = len(ns), period_ns * 1e-9
    bg = np.tile(np.asarray(imu.gyro_bias, float), (n, 1))
    ba = np.tile(np.asarray(imu.accel_bias, float), (n, 1))
    gyro, accel = w + bg, f + ba
    if imu.noise:
        rng = np.random.default_rng([imu.seed, 0x1A0])
        walk_g = rng.standard_normal((n, 3)) * imu.gyro_random_walk * np.sqrt(dt)
        walk_a = rng.standard_normal((n, 3)) * imu.accel_random_walk * np.sqrt(dt)
        walk_g[0] = walk_a[0] = 0.0
        bg += np.cumsum(walk_g, axis=0)
        ba += np.cumsum(walk_a, axis=0)
        gyro = w + bg + rng.standard_normal((n, 3)) * imu.gyro_noise_density / np.sqrt(dt)
        accel = f + ba + rng.standard_normal((n, 3)) * imu.accel_noise_density / np.sqrt(dt)
    return SyntheticImu(ns, gyro, accel, w, f, T, v, bg, ba)


def _quat_wxyz(R: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    q = Rotation.from_matrix(R).as_quat()  # x y z w
    return np.concatenate([q[:, 3:], q[:, :3]], axis=1)


def write_imu(folder: Path, config: SyntheticConfig, imu: SyntheticImuConfig) -> SyntheticImu:
    """Write :func:`simulate_imu`'s samples, calibration and ground truth into ``folder``
    (``data.csv``, ``sensor.yaml``, ``camchain-imucam.yaml``, ``groundtruth.csv``; see
    :mod:`vslam.datasets.synthetic.writer`)."""
    import yaml

    sim = simulate_imu(config, imu)
    try:
        folder.mkdir(parents=True, exist_ok=True)
        ns = sim.timestamps_ns
        header = ("#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
                  "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]\n")
        rows = np.hstack([sim.gyro, sim.accel])
        (folder / "data.csv").write_text(header + "".join(
            f"{t}," + ",".join(f"{v:.17g}" for v in r) + "\n" for t, r in zip(ns, rows)))
        T_cam_imu = np.asarray(imu.T_cam_imu, float).reshape(4, 4)
        sensor = {
            "sensor_type": "imu", "comment": "vslam synthetic IMU; T_BS is IMU -> camera (the body is the camera)",
            "T_BS": {"cols": 4, "rows": 4, "data": [float(v) for v in T_cam_imu.ravel()]},
            "rate_hz": float(imu.rate_hz),
            "gyroscope_noise_density": imu.gyro_noise_density, "gyroscope_random_walk": imu.gyro_random_walk,
            "accelerometer_noise_density": imu.accel_noise_density,
            "accelerometer_random_walk": imu.accel_random_walk,
        }
        (folder / "sensor.yaml").write_text(yaml.safe_dump(sensor, sort_keys=False))
        chain = {"cam0": {"T_cam_imu": [[float(v) for v in row] for row in T_cam_imu], "timeshift_cam_imu": 0.0}}
        (folder / "camchain-imucam.yaml").write_text(yaml.safe_dump(chain, sort_keys=False))
        gt = np.hstack([sim.T_world_imu[:, :3, 3], _quat_wxyz(sim.T_world_imu[:, :3, :3]), sim.v_world,
                        sim.gyro_bias, sim.accel_bias])
        gt_header = ("#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], "
                     "q_RS_z [], v_RS_R_x [m s^-1], v_RS_R_y [m s^-1], v_RS_R_z [m s^-1], b_w_RS_S_x [rad s^-1], "
                     "b_w_RS_S_y [rad s^-1], b_w_RS_S_z [rad s^-1], b_a_RS_S_x [m s^-2], b_a_RS_S_y [m s^-2], "
                     "b_a_RS_S_z [m s^-2]\n")
        (folder / "groundtruth.csv").write_text(gt_header + "".join(
            f"{t}," + ",".join(f"{v:.17g}" for v in r) + "\n" for t, r in zip(ns, gt)))
    except OSError as exc:
        raise DatasetError(f"{folder}: cannot write the synthetic IMU ({exc.strerror}); choose another path") from None
    return sim
