"""Sanity checks of IMU input: one clear error where a run cannot go on, a warning where it can.

* unsorted or duplicate timestamps, non-finite values: :class:`DatasetError`;
* gaps longer than :data:`MAX_GAP_S` (50 ms, ten periods at 200 Hz): a warning (preintegration
  interpolates across them);
* a gyro in degrees/s read as rad/s: :class:`DatasetError` (:func:`gyro_in_degrees`);
* no overlap with the images: :class:`DatasetError`; partial overlap: a warning.
"""
from __future__ import annotations

import logging

import numpy as np

from vslam.errors import DatasetError
from vslam.inertial.measurements import ImuMeasurements

log = logging.getLogger(__name__)

#: A gap between two samples longer than this is reported (warning).
MAX_GAP_S = 0.05
#: |w| above this is no gyro in rad/s: 35 rad/s is 2000 deg/s, the largest full scale of common
#: MEMS gyros (ADIS16448: 1000 deg/s; BMI088, ICM-20602: 2000 deg/s).
MAX_RATE_RAD_S = 35.0
#: Still-window test: over :data:`STILL_WINDOW_S`, an accelerometer whose 0.1 s means vary by less
#: than :data:`STILL_ACCEL_STD` m/s^2 (std per axis; the means remove rotor vibration: EuRoC V1_01
#: at rest, motors on, gives <= 0.10, hand-held MH_01 >= 0.3) is not turning the gravity direction;
#: a mean rate across gravity above :data:`STILL_MAX_RATE` rad/s would turn it by that many radians
#: per second (moving the accelerometer by ~g * rate, ~5 m/s^2 at 0.5 rad/s). So such a rate is a
#: gyro bias, and no MEMS gyro has a bias of 0.5 rad/s (28 deg/s; EuRoC's ADIS16448: 0.08 rad/s);
#: a gyro in deg/s shows its bias times 57.3 there.
STILL_WINDOW_S = 1.0
STILL_ACCEL_STD = 0.2
STILL_MAX_RATE = 0.5


def check_samples(imu: ImuMeasurements, where: str) -> None:
    """Raise :class:`DatasetError` (naming ``where``) for empty input, non-finite values,
    unsorted or duplicate stamps, or a gyro in degrees; warn about gaps over :data:`MAX_GAP_S`."""
    t = imu.timestamps
    if len(t) == 0:
        raise DatasetError(f"{where}: no IMU samples; the file must list 'timestamp [ns], wx, wy, wz, ax, ay, az' rows")
    bad = ~(np.isfinite(t) & np.all(np.isfinite(imu.gyro), axis=1) & np.all(np.isfinite(imu.accel), axis=1))
    if np.any(bad):
        i = int(np.argmax(bad))
        raise DatasetError(f"{where}: sample {i + 1} has a non-finite value (nan/inf); fix or remove it")
    d = np.diff(t)
    if np.any(d == 0):
        i = int(np.argmax(d == 0))
        raise DatasetError(f"{where}: duplicate timestamp at samples {i + 1} and {i + 2} ({t[i]:.9f} s); remove one")
    if np.any(d < 0):
        i = int(np.argmax(d < 0))
        raise DatasetError(
            f"{where}: timestamps are not sorted (sample {i + 2} at {t[i + 1]:.9f} s goes back in time); sort the file"
        )
    gaps = np.flatnonzero(d > MAX_GAP_S)
    if len(gaps):
        j = int(gaps[np.argmax(d[gaps])])
        log.warning(
            "%s: %d gap(s) over %.0f ms between IMU samples, the longest %.3f s after t = %.6f s; "
            "the IMU is interpolated across them", where, len(gaps), MAX_GAP_S * 1e3, d[j], t[j],
        )
    why = gyro_in_degrees(imu)
    if why:
        raise DatasetError(f"{where}: the gyro looks like degrees/s, not rad/s ({why}); convert it to rad/s "
                           f"(multiply by pi/180)")


def gyro_in_degrees(imu: ImuMeasurements) -> str | None:
    """Why the gyro columns look like degrees/s (a sentence), or None when they look like rad/s.

    Two magnitude tests (constants above): a rate beyond any gyro's range in rad/s, or, in a still
    window (the accelerometer steady to :data:`STILL_ACCEL_STD`), a mean rate across gravity that
    would have turned the accelerometer. A real gyro in rad/s passes both: EuRoC MH_01 peaks at
    0.95 rad/s (54 deg/s), and V1_01 at rest reads 0.08 rad/s.
    """
    if len(imu) == 0:
        return None
    rate = np.linalg.norm(imu.gyro, axis=1)
    peak = float(rate.max())
    if peak > MAX_RATE_RAD_S:
        return f"|w| reaches {peak:.1f}, over {MAX_RATE_RAD_S:g} rad/s (2000 deg/s, beyond any MEMS gyro's range)"
    t = imu.timestamps
    if len(t) < 3 or t[-1] - t[0] < STILL_WINDOW_S:
        return None
    starts = np.searchsorted(t, np.arange(t[0], t[-1] - STILL_WINDOW_S + 1e-9, STILL_WINDOW_S / 2))
    for i0 in starts:
        i1 = int(np.searchsorted(t, t[i0] + STILL_WINDOW_S))
        a, w = imu.accel[i0:i1], imu.gyro[i0:i1]
        if len(a) < 3 or np.max(smoothed_std(imu.timestamps[i0:i1], a)) > STILL_ACCEL_STD:
            continue
        up = a.mean(axis=0)
        n = np.linalg.norm(up)
        if n < 1e-6:
            continue
        w_mean = w.mean(axis=0)
        across = float(np.linalg.norm(w_mean - (w_mean @ up) / n**2 * up))
        if across > STILL_MAX_RATE:
            return (f"at t = {t[i0]:.3f} s the accelerometer is still but the gyro reads {across:.2f} across "
                    f"gravity, which would have turned it")
    return None


def smoothed_std(t: np.ndarray, x: np.ndarray, block_s: float = 0.1) -> np.ndarray:
    """Per-axis std ``(3,)`` of the means of ``x (N, 3)`` over consecutive ``block_s`` blocks
    (vibration averaged out; the drift of the signal is what remains)."""
    blocks = np.floor((t - t[0]) / block_s).astype(np.int64)
    counts = np.bincount(blocks)
    keep = counts > 0
    means = np.stack([np.bincount(blocks, x[:, k])[keep] / counts[keep] for k in range(x.shape[1])], axis=1)
    return means.std(axis=0) if len(means) > 1 else np.zeros(x.shape[1])


def check_overlap(imu: ImuMeasurements, t_first: float, t_last: float, where: str, time_offset: float = 0.0) -> None:
    """Images span ``[t_first, t_last]`` (camera clock); IMU time is ``t_cam + time_offset``.

    No overlap raises :class:`DatasetError`; images outside the IMU's span give a warning."""
    lo, hi = t_first + time_offset, t_last + time_offset
    first, last = imu.span
    if last < lo or first > hi:
        raise DatasetError(
            f"{where}: the IMU samples ({first:.3f} .. {last:.3f} s) do not overlap the images "
            f"({lo:.3f} .. {hi:.3f} s on the IMU clock); use the IMU file recorded with these images, "
            f"in the same time base (EuRoC: nanoseconds)"
        )
    if first > lo or last < hi:
        log.warning(
            "%s: the IMU covers %.3f .. %.3f s but the images span %.3f .. %.3f s; frames outside have no IMU",
            where, first, last, lo, hi,
        )
