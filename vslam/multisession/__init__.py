"""Many recordings mapped at once (issue #26, ``vslam map``): sessions tracked as parallel tasks
(local processes or Ray), overlaps found through one bag-of-words index over every session's
keyframes and verified per candidate pair (one task each), each connected component merged
pairwise up the tree of its strongest overlaps in parallel rounds (one task per merge), then one
pose graph over every verified overlap and one global BA per component (one task each).

Outputs in ``OUT``:

* ``sessions/<name>/``: each session's ``vslam run`` folder (reused by a rerun when complete);
* ``map/``, ``sparse.ply``, ``topology.json``, ``config.yaml``: the largest component's merged map
  (sessions as segments); other components in ``components/<i>/``; ``topology.png`` beside each
  ``topology.json`` is drawn with the report (:func:`vslam.report.multisession.draw_topologies`);
* ``trajectories/<name>.txt``: every frame of the session (TUM, ``T_world_cam``) in the common
  frame of its component (the world of the session whose keyframe ids start at 0 in its map);
* ``sessions.json``: ``sessions`` (``status``, ``error``, ``reused``, ``component``,
  ``S_common_session``, ``keyframe_offset``), ``overlaps`` (verified edges: ``inliers``, ``S_a_b``
  SE(3) / Sim(3), ``seam``, ``in_tree``: a merge used it, ``merge_error``), ``candidates`` (every pair
  verified, with its index score and outcome), ``components`` (lists of names, the largest first),
  ``component_maps`` (``tree``, ``merges``, ``pose_graph``, ``global_ba``), ``merge_rounds``,
  ``index`` (keyframes, queries, candidate pairs of all pairs), ``timing``; ``stats.json``: the
  summary; ``report.html`` (written by the CLI, :mod:`vslam.report.multisession`).

A rerun into the same ``OUT`` reuses the finished sessions and the pair verifications between
them. ``vslam map --map OUT NEW...`` (``incremental``) keeps the earlier components as they are
(their maps are the starting clusters), tracks only the new recordings, searches only the new
sessions' keyframes, verifies only pairs with a new session, and merges the new sessions into the
kept maps (a component that takes a new session gets its pose graph and global BA again).

Modules: :mod:`~vslam.multisession.sessions` (inputs, one session's task),
:mod:`~vslam.multisession.executor` (local pool / Ray), :mod:`~vslam.multisession.overlap`
(the index, candidate pairs, pair verification), :mod:`~vslam.multisession.graph`
(components, spanning tree), :mod:`~vslam.multisession.tree_merge` (the parallel rounds of merges),
:mod:`~vslam.multisession.weld` (one merge), :mod:`~vslam.multisession.global_opt` (pose graph,
global BA, a component's outputs), :mod:`~vslam.multisession.merging` (trajectories in the
common frame), :mod:`~vslam.multisession.pipeline` (:func:`map_sessions`).

Example::

    from vslam.multisession import map_sessions
    result = map_sessions(["sessions.yaml"], "out/building", executor="ray", workers=4)
    print(result["components"])
"""
from __future__ import annotations

from vslam.multisession.pipeline import map_sessions
from vslam.multisession.sessions import SessionSpec, parse_inputs

__all__ = ["SessionSpec", "map_sessions", "parse_inputs"]
