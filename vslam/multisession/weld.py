"""One merge of the tree (:mod:`vslam.multisession.tree_merge`): :func:`vslam.merge.merge_maps`
with its place recognition limited to B's keyframes at the known seam.

``merge_maps`` verifies every keyframe of B against A (ORB-SLAM3's map merge tries them all: it
does not know where the maps meet). Up the tree B is a whole cluster (up to half the component),
so that would verify ``O(K log N)`` keyframes over the tree where the session graph already knows
the seam: the keyframes of B's sessions that the verified overlaps with A's sessions matched
(``seam`` of :func:`vslam.multisession.overlap.verify_pair`). :func:`weld` runs ``merge_maps``
(find_seam -> agreeing group -> transform over all correspondences -> append -> seam fusion -> the
seam's local BA; no global BA: the component gets one at the end) with ``b_keyframes`` = those.

At the known seam each of those keyframes is verified against A's best 2 bag-of-words candidates
(:data:`SEAM_CANDIDATES`; ``vslam merge``, which does not know the seam, tries 3): the pair
verification already found that B's keyframe sees A there. Measured (round 5 of
``benchmarks/RESULTS.md``), merge stage wall time and ATE with one alignment, 3 / 2 / 1 candidates:
the 16-arc fleet, sequential 12.1 / 9.1 / 5.8 s, 0.0059 m each; 7-Scenes in 5 sessions, 2 workers,
7.5 / 5.7 / 3.7 s, 0.0462 / 0.0463 / 0.0468 m (one candidate drops a seam keyframe of two merges).
Without a known seam (``b_keyframes`` None) the default 3 stay.
"""
from __future__ import annotations

import time
from typing import Any

#: A's bag-of-words candidates verified per B keyframe at a known seam (module docstring)
SEAM_CANDIDATES = 2


def weld(map_a, db_a, map_b, db_b, camera, sensor: str, cfg, b_keyframes: list[int] | None,
         source_b: str = "", threads: int = 1) -> dict[str, Any]:
    """Merge ``map_b`` into ``map_a`` (in place; ``db_b``'s vectors join ``db_a`` under the new ids),
    place recognition on ``b_keyframes`` of B (all when None) in ``threads`` threads. Returns the statistics, with
    ``S_a_b`` and ``keyframe_id_offset``. Raises :class:`vslam.errors.MergeError` when no overlap."""
    from vslam.merge import MergeOptions, merge_maps

    t0 = time.perf_counter()
    options = MergeOptions(global_ba=False, candidates=SEAM_CANDIDATES if b_keyframes else MergeOptions.candidates,
                           threads=threads)
    res = merge_maps(map_a, db_a, map_b, db_b, camera, sensor, cfg, options=options, source_b=source_b,
                     b_keyframes=b_keyframes)
    st, ba = res.stats, res.stats.get("local_ba") or {}
    keep = ("keyframes", "queried_b_keyframes", "seam_keyframes", "weak_seam_keyframes", "alignment_inliers",
            "fused_points", "scale", "keyframe_id_offset")
    return {**{k: st[k] for k in keep}, "S_a_b": res.S_a_b, "local_ba_s": round(ba.get("ms", 0.0) / 1e3, 2),
            "threads": threads, "weld_s": round(time.perf_counter() - t0, 2)}
