"""Synthetic sequences with exact ground truth: a textured room, a ray-cast renderer, camera paths.

In memory::

    seq = SyntheticSequence(SyntheticConfig(n_frames=60, pixel_noise=2.0))
    frame = seq[0]          # Frame: image, image_right, depth, camera (with baseline), T_world_cam

On disk (TUM layout, read back with ``vslam.datasets.open_dataset``)::

    render_sequence("out/sequence", SyntheticConfig(n_frames=300))

Many sessions through the one room, for ``vslam map`` (:mod:`~vslam.datasets.synthetic.fleet`)::

    render_fleet("out/fleet", 16)   # out/fleet/s00 ... s15, lone, sessions.yaml, fleet.json
"""
from __future__ import annotations

from vslam.datasets.synthetic.fleet import FleetSequence, FleetSession, fleet_sessions, render_fleet
from vslam.datasets.synthetic.imu import SyntheticImu, SyntheticImuConfig, simulate_imu
from vslam.datasets.synthetic.plot import plot_ground_truth_topdown
from vslam.datasets.synthetic.renderer import Renderer, default_renderer, render
from vslam.datasets.synthetic.scene import (
    Box, Face, Scene, SceneSpec, build_scene, default_scene, distance_to_scene, sample_surface_points,
)
from vslam.datasets.synthetic.sequence import (
    SyntheticConfig, SyntheticSequence, add_depth_noise, add_pixel_noise, missing_depth_mask, right_from_left,
)
from vslam.datasets.synthetic.trajectory import forward_path, look_rotation, loop_path, make_path
from vslam.datasets.synthetic.writer import DEPTH_SCALE, depth_to_png, render_sequence

__all__ = [
    "Box", "DEPTH_SCALE", "FleetSequence", "FleetSession", "fleet_sessions", "render_fleet", "SyntheticImu", "SyntheticImuConfig", "simulate_imu", "Face", "Renderer", "Scene", "SceneSpec", "SyntheticConfig", "SyntheticSequence",
    "add_depth_noise", "add_pixel_noise", "build_scene", "default_renderer", "default_scene", "depth_to_png",
    "distance_to_scene",
    "forward_path", "look_rotation", "loop_path", "make_path", "missing_depth_mask",
    "plot_ground_truth_topdown", "render", "render_sequence", "right_from_left", "sample_surface_points",
]
