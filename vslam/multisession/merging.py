"""Merging one component of the session graph along its spanning tree, and each session's
trajectory in the component's common frame (step 3 of :mod:`vslam.multisession`).

The root is the component's session with the most keyframes; its world is the common frame. The
others are merged one after the other, breadth first along the tree, each into the growing map with
:func:`vslam.merge.merge_maps` (place recognition against the whole merged map so far, one SE(3) /
Sim(3), seam fusion, the seam's local BA); the last merge adds a global BA over everything. A
tree merge that finds no overlap after all raises :class:`TreeMergeFailed` (the caller drops that
edge and splits the component). Sequential in this first version: the tree's merges do not run in
parallel.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from vslam.errors import MergeError
from vslam.multisession.graph import merge_order


class TreeMergeFailed(Exception):
    def __init__(self, parent: str, child: str, message: str) -> None:
        super().__init__(f"merging {child} into the map of {parent}'s component failed: {message}")
        self.parent, self.child, self.message = parent, child, message


@dataclass
class Placement:
    """Where a session went: ``S`` (its world -> the common frame), keyframe id ``offset`` in the
    merged map, and its keyframes' poses before (``{kf id: T_world_cam}`` in its own world)."""

    S: np.ndarray
    offset: int
    keyframes: dict[int, np.ndarray]


@dataclass
class ComponentMap:
    names: list[str]
    root: str
    map: Any
    database: Any
    camera: Any
    metadata: dict
    placements: dict[str, Placement] = field(default_factory=dict)
    merges: list[dict] = field(default_factory=list)


def _poses(slam_map) -> dict[int, np.ndarray]:
    return {k: kf.T_world_cam.copy() for k, kf in slam_map.keyframes.items() if not kf.bad}


def merge_component(names: list[str], folders: dict[str, Path], tree: list[dict], keyframes: dict[str, int],
                    config: str | None = None, overrides: tuple[str, ...] = ()) -> ComponentMap:
    """The merged map of one component (see the module docstring)."""
    from vslam.api import resolve_config
    from vslam.map.io import load_run_map
    from vslam.merge import MergeOptions, merge_maps

    root = max(names, key=lambda n: (keyframes.get(n, 0), -names.index(n)))
    slam_map, db, cam, meta = load_run_map(folders[root], f"session {root}", "merge")
    comp = ComponentMap(names, root, slam_map, db, cam, dict(meta))
    comp.placements[root] = Placement(np.eye(4), 0, _poses(slam_map))
    order = merge_order(root, tree)
    if not order:
        return comp
    cfg_file = config or (str(folders[root] / "config.yaml") if (folders[root] / "config.yaml").is_file() else None)
    cfg = resolve_config(cfg_file, list(overrides))
    sensor = meta.get("sensor")
    for i, (parent, child) in enumerate(order):
        t0 = time.perf_counter()
        map_b, db_b, _, _ = load_run_map(folders[child], f"session {child}", "merge")
        before = _poses(map_b)
        last = i == len(order) - 1
        try:
            res = merge_maps(comp.map, comp.database, map_b, db_b, cam, sensor, cfg,
                             options=MergeOptions(global_ba=last), source_b=str(folders[child].resolve()))
        except MergeError as exc:
            raise TreeMergeFailed(parent, child, str(exc)) from exc
        comp.database = res.database
        s = res.stats
        comp.placements[child] = Placement(np.asarray(res.S_a_b, float), int(s["keyframe_id_offset"]), before)
        comp.merges.append({"parent": parent, "child": child, "seam_keyframes": s["seam_keyframes"],
                            "alignment_inliers": s["alignment_inliers"], "scale": s["scale"],
                            "fused_points": s["fused_points"], "global_ba": last,
                            "merge_s": round(time.perf_counter() - t0, 2)})
    comp.metadata["sessions"] = names
    comp.metadata["merged"] = list(comp.metadata.get("merged", [])) + [
        {"a": str(folders[m["parent"]].resolve()), "b": str(folders[m["child"]].resolve()),
         "S_a_b": comp.placements[m["child"]].S.round(6).tolist(), "seam_keyframes": m["seam_keyframes"]}
        for m in comp.merges]
    return comp


def _sim3_poses(S: np.ndarray, T: np.ndarray) -> np.ndarray:
    """Camera poses ``T (N, 4, 4)`` moved by the Sim(3) ``S``: rotation ``R_S R``, centre ``S c``."""
    s = float(np.cbrt(np.linalg.det(S[:3, :3])))
    out = T.copy()
    out[:, :3, :3] = (S[:3, :3] / s) @ T[:, :3, :3]
    out[:, :3, 3] = T[:, :3, 3] @ S[:3, :3].T + S[:3, 3]
    return out


def session_trajectory(comp: ComponentMap, name: str, folder: Path):
    """The session's ``trajectory.txt`` in the component's common frame: every frame moved by the
    session's ``S``, then by the correction the merges' BA gave its reference keyframe (the last
    keyframe at or before the frame; the first for earlier frames)."""
    from vslam.geometry.lie import inv_se3
    from vslam.trajectory import Trajectory, read_tum

    traj = read_tum(folder / "trajectory.txt")
    p = comp.placements[name]
    T = _sim3_poses(p.S, traj.T_world_cam)
    kf_ids = sorted(k for k in p.keyframes if (k + p.offset) in comp.map.keyframes
                    and not comp.map.keyframes[k + p.offset].bad)
    if not kf_ids:
        return Trajectory(traj.timestamps, T)
    kf_t = np.array([comp.map.keyframes[k + p.offset].timestamp for k in kf_ids])
    order = np.argsort(kf_t, kind="stable")
    kf_ids, kf_t = [kf_ids[i] for i in order], kf_t[order]
    before = _sim3_poses(p.S, np.stack([p.keyframes[k] for k in kf_ids]))
    after = np.stack([comp.map.keyframes[k + p.offset].T_world_cam for k in kf_ids])
    corrections = after @ inv_se3(before)
    ref = np.clip(np.searchsorted(kf_t, traj.timestamps + 1e-9, side="right") - 1, 0, len(kf_ids) - 1)
    return Trajectory(traj.timestamps, corrections[ref] @ T)
