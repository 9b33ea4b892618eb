"""A synthetic fleet: N short sessions through the one textured room, for ``vslam map`` (issue #26).

Every session is its own recording in TUM layout (:func:`render_fleet`), with exact ground truth in
the room's world frame (``groundtruth.txt``); ``vslam run`` knows nothing of it and starts each
session at its own origin, so the start poses are unknown to the mapper.

Paths (``n_frames`` each, 320 x 240 RGB-D, mild pixel and depth noise, seed per session):

* session ``k < 16`` (``s00`` ...) is an arc of the room loop (:func:`~vslam.datasets.synthetic.trajectory.loop_poses`)
  over phases ``[k, k + 2] * 2 pi / 16``: session ``k`` overlaps ``k + 1`` over half its path
  (and touches ``k + 2`` at its end); sixteen of them close the loop (``s15`` overlaps ``s00``). Heights
  1.3 / 1.4 / 1.5 m and the loop's radii scaled by 1 or 0.92 alternate, so no two paths coincide;
* sessions ``16 .. 31`` are a second, inner ring (radii x 0.75, height 1.25 m) half a step out of
  phase with the first, each overlapping its ring neighbours and the outer arcs at the same phases;
* ``lone`` (when asked) looks straight up at the middle of the ceiling from under it, turning slowly
  on a small circle: no other session sees that part of the room (the loop's views rise at most
  24 degrees above the horizon, so the ceiling they see is over 3 m away, near the walls), so it
  overlaps nothing and must come out as its own component.

``sessions.yaml`` in the output folder is the input of ``vslam map``; ``fleet.json`` lists the
sessions, the overlaps by construction and the lone one.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from vslam.datasets.synthetic.sequence import SyntheticConfig, SyntheticSequence
from vslam.datasets.synthetic.trajectory import loop_poses, poses_from
from vslam.errors import ConfigError

STEP = 2.0 * np.pi / 16  # phase between consecutive arcs of one ring
RING = 16  # arcs per ring
LONE = "lone"


@dataclass(frozen=True)
class FleetSession:
    """One session of the fleet: its name, its exact ``T_world_cam (n, 4, 4)`` and the sessions it
    overlaps by construction."""

    name: str
    T_world_cam: np.ndarray = field(repr=False)
    overlaps: tuple[str, ...] = ()


def session_name(k: int) -> str:
    return f"s{k:02d}"


def arc_poses(k: int, n_frames: int) -> np.ndarray:
    """Session ``k``'s path (module docstring)."""
    ring, j = divmod(k, RING)
    phi0 = (j + 0.5 * ring) * STEP
    phi = phi0 + 2.0 * STEP * np.arange(n_frames) / max(n_frames - 1, 1)
    if ring == 0:
        scale, height = (1.0, 0.92)[k % 2], (1.4, 1.5, 1.3)[k % 3]
    else:
        scale, height = 0.75, 1.25
    return loop_poses(phi, radii=(1.8 * scale, 1.2 * scale), height=height)


def lone_poses(n_frames: int) -> np.ndarray:
    """Under the middle of the ceiling, looking up, turning 60 degrees on a 0.25 m circle."""
    s = np.arange(n_frames) / max(n_frames - 1, 1)
    a = np.deg2rad(60.0) * s
    pos = np.stack([0.25 * np.cos(a), 0.25 * np.sin(a), 1.55 + 0.05 * s], axis=1)
    pitch = np.deg2rad(85.0) + np.deg2rad(3.0) * np.sin(2.0 * np.pi * s)
    return poses_from(pos, a + np.deg2rad(10.0), pitch)


def fleet_sessions(n_sessions: int, n_frames: int = 50, lone: bool = True) -> list[FleetSession]:
    """The ``n_sessions`` arcs (at most 32) plus, with ``lone``, the session that overlaps nothing."""
    if not 1 <= n_sessions <= 2 * RING:
        raise ConfigError(f"a fleet has 1 to {2 * RING} overlapping sessions, not {n_sessions}")
    names = [session_name(k) for k in range(n_sessions)]
    starts = [(k % RING + 0.5 * (k // RING)) for k in range(n_sessions)]  # in steps; arcs span 2 steps
    out = []
    for k in range(n_sessions):
        # arcs whose phase ranges share at least half a step (round the loop) overlap by construction
        near = [names[m] for m in range(n_sessions)
                if m != k and abs((starts[m] - starts[k] + RING / 2) % RING - RING / 2) <= 1.5]
        out.append(FleetSession(names[k], arc_poses(k, n_frames), tuple(near)))
    if lone:
        out.append(FleetSession(LONE, lone_poses(n_frames)))
    return out


def session_config(index: int, n_frames: int) -> SyntheticConfig:
    """320 x 240 RGB-D with mild noise (as the demo's); timestamps ``1000 * (index + 1) + i / 30`` s
    so that no two sessions share one."""
    return SyntheticConfig(
        n_frames=n_frames, width=320, height=240, fx=262.5, fy=262.5, cx=159.5, cy=119.5, stereo=False,
        pixel_noise=1.0, depth_noise=0.002, depth_noise_model="proportional", seed=100 + index,
        start_time=1000.0 * (index + 1),
    )


class FleetSequence(SyntheticSequence):
    """A :class:`SyntheticSequence` along given poses (``len(T_world_cam) == config.n_frames``)."""

    def __init__(self, config: SyntheticConfig, T_world_cam: np.ndarray, name: str = "fleet") -> None:
        super().__init__(config)
        if len(T_world_cam) != config.n_frames:
            raise ConfigError(f"{len(T_world_cam)} poses for {config.n_frames} frames")
        self.T_world_cam = np.asarray(T_world_cam, dtype=float).copy()
        self.name = f"synthetic-{name}"


def render_fleet(out_dir: str | Path, n_sessions: int, n_frames: int = 50, lone: bool = True) -> dict:
    """Render the fleet into ``out_dir/<name>/`` (TUM layout each) and write ``sessions.yaml`` (the
    ``vslam map`` input, RGB-D) and ``fleet.json``; returns ``fleet.json``'s content. Sessions
    already rendered (their ``groundtruth.txt`` present) are kept."""
    from vslam.datasets.synthetic.writer import render_sequence

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    sessions = fleet_sessions(n_sessions, n_frames, lone)
    for i, s in enumerate(sessions):
        folder = out / s.name
        if not (folder / "groundtruth.txt").is_file():
            cfg = session_config(i if s.name != LONE else 99, n_frames)
            render_sequence(folder, cfg, sequence=FleetSequence(cfg, s.T_world_cam, s.name))
    lines = ["sessions:"] + [f"  - {{name: {s.name}, data: {s.name}, sensor: rgbd}}" for s in sessions]
    (out / "sessions.yaml").write_text("\n".join(lines) + "\n")
    doc = {"sessions": [s.name for s in sessions], "frames": n_frames, "lone": LONE if lone else None,
           "overlaps": {s.name: list(s.overlaps) for s in sessions}}
    (out / "fleet.json").write_text(json.dumps(doc, indent=1))
    return doc
