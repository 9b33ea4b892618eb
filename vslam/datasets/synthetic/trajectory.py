"""Exact camera paths through the synthetic room, as ``(N, 4, 4)`` ``T_world_cam`` poses.

Camera convention: x right, y down, z forward. World: z up. A camera with yaw ``psi`` (heading in
the horizontal plane, 0 = +x, counter-clockwise) and pitch ``theta`` (positive = looking up) has
``z_cam = (cos(theta) cos(psi), cos(theta) sin(psi), sin(theta))``, ``x_cam = (sin(psi), -cos(psi), 0)``
and ``y_cam = z_cam x x_cam``; these are the columns of ``R_world_cam``.
"""
from __future__ import annotations

import numpy as np


def look_rotation(yaw: np.ndarray, pitch: np.ndarray) -> np.ndarray:
    """``R_world_cam (N, 3, 3)`` for yaw/pitch angles in radians (no roll)."""
    yaw = np.atleast_1d(np.asarray(yaw, dtype=float))
    pitch = np.atleast_1d(np.asarray(pitch, dtype=float))
    z = np.stack([np.cos(pitch) * np.cos(yaw), np.cos(pitch) * np.sin(yaw), np.sin(pitch)], axis=1)
    x = np.stack([np.sin(yaw), -np.cos(yaw), np.zeros_like(yaw)], axis=1)
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=2)


def poses_from(positions: np.ndarray, yaw: np.ndarray, pitch: np.ndarray) -> np.ndarray:
    T = np.tile(np.eye(4), (len(positions), 1, 1))
    T[:, :3, :3] = look_rotation(yaw, pitch)
    T[:, :3, 3] = positions
    return T


def loop_path(
    n_frames: int,
    laps: float = 1.0,
    radii: tuple[float, float] = (1.8, 1.2),
    height: float = 1.4,
    center: tuple[float, float] = (0.0, 0.0),
) -> np.ndarray:
    """An elliptical loop round the room centre, looking ahead and inwards with smooth yaw/pitch.

    Frame ``i`` is at phase ``phi = 2 pi laps i / (n_frames - 1)``; everything (position, yaw
    offset, pitch, height bob) is periodic in ``phi``, so with ``laps = 1`` the last pose equals the
    first exactly and with ``laps > 1`` the start of the loop is revisited after ``(n-1)/laps`` frames.
    """
    phi = 2.0 * np.pi * laps * np.arange(n_frames) / max(n_frames - 1, 1)
    return loop_poses(phi, radii, height, center)


def loop_poses(
    phi: np.ndarray,
    radii: tuple[float, float] = (1.8, 1.2),
    height: float = 1.4,
    center: tuple[float, float] = (0.0, 0.0),
) -> np.ndarray:
    """The poses of :func:`loop_path` at any phases ``phi (N,)`` (a smooth, analytic function of
    ``phi``: the synthetic IMU differentiates it)."""
    phi = np.asarray(phi, dtype=float)
    a, b = radii
    pos = np.stack([
        center[0] + a * np.cos(phi),
        center[1] + b * np.sin(phi),
        height + 0.08 * np.sin(2.0 * phi),
    ], axis=1)
    heading = np.arctan2(b * np.cos(phi), -a * np.sin(phi))
    # 45 deg left of the direction of travel (inwards, across the room: the loop runs
    # counter-clockwise), swinging +-20 deg against the turn at the tight ends of the ellipse so
    # the rotation rate stays moderate; depths span about 0.9-5 m
    yaw = heading + np.deg2rad(45.0) - np.deg2rad(20.0) * np.sin(2.0 * phi)
    pitch = np.deg2rad(-8.0) + np.deg2rad(7.0) * np.sin(3.0 * phi)
    return poses_from(pos, yaw, pitch)


def forward_path(
    n_frames: int,
    start: tuple[float, float, float] = (-2.2, -0.8, 1.3),
    end: tuple[float, float, float] = (1.9, -0.8, 1.35),
) -> np.ndarray:
    """A straight forward motion along the optical axis (with a gentle yaw/pitch sway)."""
    return forward_poses(np.linspace(0.0, 1.0, n_frames), start, end)


def forward_poses(
    s: np.ndarray,
    start: tuple[float, float, float] = (-2.2, -0.8, 1.3),
    end: tuple[float, float, float] = (1.9, -0.8, 1.35),
) -> np.ndarray:
    """The poses of :func:`forward_path` at any path fractions ``s (N,)`` (0: start, 1: end)."""
    s = np.asarray(s, dtype=float)[:, None]
    start_a, end_a = np.asarray(start, float), np.asarray(end, float)
    pos = start_a + s * (end_a - start_a)
    dx, dy, dz = end_a - start_a
    heading = np.arctan2(dy, dx)
    base_pitch = np.arctan2(dz, np.hypot(dx, dy))
    phase = 2.0 * np.pi * s[:, 0]
    yaw = heading + np.deg2rad(6.0) * np.sin(phase)
    pitch = base_pitch + np.deg2rad(-5.0) + np.deg2rad(3.0) * np.sin(2.0 * phase)
    return poses_from(pos, yaw, pitch)


def path_at(kind: str, u: np.ndarray, n_frames: int, laps: float = 1.0) -> np.ndarray:
    """``T_world_cam (N, 4, 4)`` of :func:`make_path`'s path at fractional frame indices ``u (N,)``
    (``u = i`` gives frame ``i``'s pose up to rounding; values outside ``[0, n_frames - 1]``
    continue the same analytic path)."""
    u = np.asarray(u, dtype=float)
    if kind == "loop":
        return loop_poses(2.0 * np.pi * laps * u / max(n_frames - 1, 1))
    if kind == "forward":
        return forward_poses(u / max(n_frames - 1, 1))
    return make_path(kind, n_frames, laps)  # raises for an unknown kind


def make_path(kind: str, n_frames: int, laps: float = 1.0) -> np.ndarray:
    """``"loop"`` or ``"forward"`` poses."""
    if kind == "loop":
        return loop_path(n_frames, laps=laps)
    if kind == "forward":
        return forward_path(n_frames)
    from vslam.errors import ConfigError

    raise ConfigError(f"unknown synthetic path kind {kind!r}; use 'loop' or 'forward'")
