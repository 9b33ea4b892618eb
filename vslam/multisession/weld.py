"""One merge of the tree (:mod:`vslam.multisession.tree_merge`): :func:`vslam.merge.merge_maps`
with its place recognition limited to B's keyframes at the known seam.

``merge_maps`` verifies every keyframe of B against A (ORB-SLAM3's map merge tries them all: it
does not know where the maps meet). Up the tree B is a whole cluster (up to half the component),
so that would verify ``O(K log N)`` keyframes over the tree where the session graph already knows
the seam: the keyframes of B's sessions that the verified overlaps with A's sessions matched
(``seam`` of :func:`vslam.multisession.overlap.verify_pair`). :func:`weld` runs the same steps
(find_seam -> agreeing group -> transform over all correspondences -> append -> seam fusion
-> the seam's local BA) with place recognition on those keyframes only; the agreeing group, the
weak matches that agree with the transform (a second place where the clusters meet, e.g. a ring
closing) and the fusion are ``merge_maps``'s.

(Duplicates ~30 lines of :func:`vslam.merge.merge_maps`: a ``b_keyframes`` option there would let
this module call it; see the issue #26 report.)
"""
from __future__ import annotations

import logging
import time
from types import SimpleNamespace
from typing import Any

import numpy as np

log = logging.getLogger(__name__)


def _agrees(S_match: np.ndarray, S: np.ndarray, T_world_cam: np.ndarray, tolerance: float, agree_deg: float) -> bool:
    """Whether a match's transform places its B keyframe within ``tolerance`` / ``agree_deg`` of ``S``'s."""
    A, B = S @ T_world_cam, S_match @ T_world_cam
    Ra = A[:3, :3] / np.cbrt(np.linalg.det(A[:3, :3]))
    Rb = B[:3, :3] / np.cbrt(np.linalg.det(B[:3, :3]))
    ang = float(np.degrees(np.arccos(np.clip((np.trace(Ra.T @ Rb) - 1.0) / 2.0, -1.0, 1.0))))
    return bool(np.linalg.norm(A[:3, 3] - B[:3, 3]) <= tolerance and ang <= agree_deg)


def weld(map_a, db_a, map_b, db_b, camera, sensor: str, cfg, b_keyframes: list[int] | None,
         source_b: str = "") -> dict[str, Any]:
    """Merge ``map_b`` into ``map_a`` (in place; ``db_b``'s vectors join ``db_a`` under the new ids),
    place recognition on ``b_keyframes`` of B (all when None). Returns the statistics, with
    ``S_a_b`` and ``keyframe_id_offset``. Raises :class:`vslam.errors.MergeError` when no overlap."""
    from vslam.backend.local_mapping import LocalMapper
    from vslam.errors import MergeError
    from vslam.loop.vocabulary import load_default_vocabulary
    from vslam.map.append import append_map
    from vslam.map.segment_merge import fuse_seam
    from vslam.merge import MergeOptions, agreeing_group, estimate_transform, find_seam

    t0 = time.perf_counter()
    options = MergeOptions(global_ba=False)
    vocabulary = load_default_vocabulary()
    keep = sorted(k for k in (b_keyframes or map_b.keyframes) if k in map_b.keyframes)
    sub_b = SimpleNamespace(keyframes={k: map_b.keyframes[k] for k in keep}, points=map_b.points)
    matches = find_seam(map_a, db_a, sub_b, db_b, camera, sensor, cfg, vocabulary, options)
    centres = np.stack([k.T_world_cam[:3, 3] for k in map_a.keyframes.values()])
    extent = float(np.linalg.norm(centres - centres.mean(axis=0), axis=1).max())
    tol = options.agree_rel * max(extent, 1e-6) if sensor == "mono" else options.agree_m
    cc = cfg.loop.closing
    need = cc.min_inliers_mono if sensor == "mono" else cc.min_inliers
    group = agreeing_group([m for m in matches if m.ver.n_inliers >= need], map_b, tol, options.agree_deg)
    if len(group) < options.min_agreeing:
        raise MergeError(f"the clusters do not overlap at their seam: {len(matches)} of {len(keep)} seam keyframes of "
                         f"B were verified in A and at most {len(group)} agree ({options.min_agreeing} needed)")
    S, alignment = estimate_transform(group, map_a, sensor)
    ids = {m.b_kf for m in group}
    weak = [m for m in matches if m.b_kf not in ids
            and _agrees(m.S_a_b, S, map_b.keyframes[m.b_kf].T_world_cam, tol, options.agree_deg)]
    best = max(group, key=lambda m: m.ver.n_inliers)
    seg_a, seg_b = map_a.keyframes[best.a_kf].segment, map_b.keyframes[best.b_kf].segment
    off = append_map(map_a, map_b, S, source=source_b, segment_map={seg_b: seg_a}).kf_offset
    for k in sorted(map_b.keyframes):
        if db_b is not None and k in db_b:
            db_a.add(k + off, db_b.bow(k))
    # seam fusion as merge_maps: each match's inliers, then A's points of the matched places
    # projected into B's seam keyframes and their covisible keyframes (A's point survives)
    seam = group + weak
    b_ids = {m.b_kf + off for m in seam}
    a_group = sorted({k for m in seam for k in [m.a_kf] + map_a.covisible(m.a_kf, cc.candidate_neighbours) if k < off})
    targets = sorted(b_ids | {k for b in b_ids for k in map_a.covisible(b, cc.candidate_neighbours) if k >= off})
    fused = fuse_seam(map_a, [(m.b_kf + off, m.ver.kp_idx, m.ver.point_ids) for m in seam], targets, a_group,
                      camera, sensor, cc.fuse.radius_px, cc.fuse.max_descriptor_distance, cc.fuse.ratio)
    for k in sorted(map_a.keyframes):
        if k >= off and map_a.keyframes[k].segment == seg_a:
            map_a.update_covisibility(k)
    t_ba = time.perf_counter()
    LocalMapper(map_a, camera, sensor, cfg.backend, cfg.features.scale_factor).process(best.b_kf + off)
    return {"S_a_b": S, "keyframe_id_offset": off, "keyframes": len(map_a.keyframes),
            "queried_b_keyframes": len(keep), "seam_keyframes": len(group), "weak_seam_keyframes": len(weak),
            "alignment_inliers": alignment["inliers"], "fused_points": int(fused),
            "scale": round(float(np.cbrt(np.linalg.det(S[:3, :3]))), 6),
            "local_ba_s": round(time.perf_counter() - t_ba, 2), "weld_s": round(time.perf_counter() - t0, 2)}
