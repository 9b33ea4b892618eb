"""IMU samples: timestamps (s), gyro (rad/s) and accelerometer (m/s^2) in the IMU frame.

Example:
    >>> import numpy as np
    >>> t = np.arange(5) * 0.005
    >>> imu = ImuMeasurements(t, np.zeros((5, 3)), np.tile([0.0, 0.0, 9.81], (5, 1)))
    >>> len(imu.between(0.004, 0.016))
    3
    >>> imu.interval(0.0025, 0.0125).timestamps.tolist()
    [0.0025, 0.005, 0.01, 0.0125]
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vslam.errors import DatasetError


@dataclass(frozen=True)
class ImuMeasurements:
    """IMU samples, sorted by time.

    Attributes:
        timestamps: ``(N,)`` seconds, strictly increasing (float64; EuRoC ns / 1e9).
        gyro: ``(N, 3)`` angular velocity ``w_RS_S`` in the IMU frame, rad/s.
        accel: ``(N, 3)`` specific force ``a_RS_S`` in the IMU frame, m/s^2 (at rest: +g up).
        source: where the samples came from (a file name), for messages.
    """

    timestamps: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray
    source: str = ""

    def __post_init__(self) -> None:
        t = np.ascontiguousarray(self.timestamps, dtype=np.float64).reshape(-1)
        g = np.ascontiguousarray(self.gyro, dtype=np.float64)
        a = np.ascontiguousarray(self.accel, dtype=np.float64)
        if g.shape != (len(t), 3) or a.shape != (len(t), 3):
            raise DatasetError(
                f"{self.source or 'IMU samples'}: gyro {g.shape} and accel {a.shape} must both be ({len(t)}, 3)"
            )
        object.__setattr__(self, "timestamps", t)
        object.__setattr__(self, "gyro", g)
        object.__setattr__(self, "accel", a)

    def __len__(self) -> int:
        return len(self.timestamps)

    def __repr__(self) -> str:
        span = f", {self.timestamps[0]:.6f} .. {self.timestamps[-1]:.6f} s" if len(self) else ""
        return f"ImuMeasurements({len(self)} samples{span}, source={self.source!r})"

    @property
    def span(self) -> tuple[float, float]:
        """``(first, last)`` sample time, seconds."""
        return float(self.timestamps[0]), float(self.timestamps[-1])

    def _take(self, sl: slice | np.ndarray) -> "ImuMeasurements":
        return ImuMeasurements(self.timestamps[sl], self.gyro[sl], self.accel[sl], self.source)

    def between(self, t0: float, t1: float) -> "ImuMeasurements":
        """The samples with ``t0 <= t <= t1`` (no interpolation)."""
        i0 = int(np.searchsorted(self.timestamps, t0, side="left"))
        i1 = int(np.searchsorted(self.timestamps, t1, side="right"))
        return self._take(slice(i0, max(i0, i1)))

    def at(self, t: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """``(gyro, accel)`` linearly interpolated at ``t`` (held constant outside the samples)."""
        tt = np.atleast_1d(np.asarray(t, dtype=float))
        g = np.stack([np.interp(tt, self.timestamps, self.gyro[:, k]) for k in range(3)], axis=1)
        a = np.stack([np.interp(tt, self.timestamps, self.accel[:, k]) for k in range(3)], axis=1)
        return g, a

    def interval(self, t0: float, t1: float) -> "ImuMeasurements":
        """The samples strictly inside ``(t0, t1)`` plus samples linearly interpolated at exactly
        ``t0`` and ``t1`` (the partial first and last sample periods, as ORB-SLAM3's
        ``Tracking::PreintegrateIMU`` does). Raises :class:`DatasetError` when the samples do not
        cover ``[t0, t1]``."""
        if not t1 > t0:
            raise DatasetError(f"{self.source or 'IMU'}: empty interval [{t0!r}, {t1!r}]")
        if len(self) < 2 or t0 < self.timestamps[0] or t1 > self.timestamps[-1]:
            first, last = (self.span if len(self) else (float("nan"), float("nan")))
            raise DatasetError(
                f"{self.source or 'IMU'}: samples cover [{first:.6f}, {last:.6f}] s, not the interval "
                f"[{t0:.6f}, {t1:.6f}] s; the IMU file must span the images"
            )
        # the samples inside and their brackets: np.interp on them picks the same bracketing pair
        # (same values) as on the whole series, and the strict inside is the same set of samples
        lo = int(np.searchsorted(self.timestamps, t0, side="right"))
        hi = int(np.searchsorted(self.timestamps, t1, side="left"))
        g_end, a_end = self._take(slice(max(lo - 1, 0), hi + 1)).at([t0, t1])
        inner = slice(lo, max(lo, hi))
        t = np.concatenate([[t0], self.timestamps[inner], [t1]])
        g = np.concatenate([g_end[:1], self.gyro[inner], g_end[1:]])
        a = np.concatenate([a_end[:1], self.accel[inner], a_end[1:]])
        return ImuMeasurements(t, g, a, self.source)
