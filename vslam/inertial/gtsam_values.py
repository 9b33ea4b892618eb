"""Fast writes of IMU velocities and biases into a :class:`gtsam.Values`.

``gtsam.Values.update(key, ConstantBias)`` resolves its argument through some thirty pybind
overloads (about 25 us a call, most of a VI-BA's cost evaluation); ``update(Values)`` is the first
overload (under 1 us). :class:`StateWriter` therefore writes the velocities (``Vector3``) and biases
of a fixed set of keys as one ``Values``: a zero-valued template retracted by the new values. Both
retractions are additions to zero (``Vector3``: ``0 + v``; ``ConstantBias``: ``(0 + b_a, 0 + b_g)``),
so the written values are exactly the given ones::

    writer = StateWriter([1, 4], [2, 5])
    writer.write(values, [v1, v4], [b2, b5])    # b: (6,) GTSAM order, accelerometer then gyro
"""
from __future__ import annotations

import functools

import numpy as np


@functools.lru_cache(maxsize=256)
def _zero_template(vel_keys: tuple, bias_keys: tuple):
    """Zero velocities and biases under the keys (read only: only ever retracted, which copies)."""
    import gtsam

    zero = gtsam.Values()
    for k in vel_keys:
        zero.insert(k, np.zeros(3))
    for k in bias_keys:
        zero.insert(k, gtsam.imuBias.ConstantBias())
    return zero


class StateWriter:
    """Writes velocities under ``vel_keys`` and biases under ``bias_keys`` (module docstring)."""

    def __init__(self, vel_keys, bias_keys) -> None:
        self.vel_keys = [int(k) for k in vel_keys]
        self.bias_keys = [int(k) for k in bias_keys]
        self._zero = _zero_template(tuple(self.vel_keys), tuple(self.bias_keys))

    def values(self, velocities, biases):
        """A new :class:`gtsam.Values` with ``velocities[i]`` at ``vel_keys[i]`` and ``biases[i]`` (6,
        accelerometer then gyro) at ``bias_keys[i]``."""
        import gtsam

        delta = gtsam.VectorValues()
        for k, v in zip(self.vel_keys, velocities):
            delta.insert(k, np.asarray(v, float).reshape(3))
        for k, b in zip(self.bias_keys, biases):
            delta.insert(k, np.asarray(b, float).reshape(6))
        return self._zero.retract(delta)

    def write(self, values, velocities, biases) -> None:
        """Set the keys in ``values`` (inserted when ``values`` has none of them yet)."""
        new = self.values(velocities, biases)
        if self.vel_keys and values.exists(self.vel_keys[0]) or self.bias_keys and values.exists(self.bias_keys[0]):
            values.update(new)
        else:
            values.insert(new)
