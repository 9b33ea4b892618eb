"""Many recordings mapped at once (issue #26, ``vslam map``): sessions tracked as parallel tasks
(local processes or Ray), overlaps found through one bag-of-words index over every session's
keyframes and verified per candidate pair, then each connected component merged along the
spanning tree of its strongest overlaps.

Outputs in ``OUT``:

* ``sessions/<name>/``: each session's ``vslam run`` folder (reused by a rerun when complete);
* ``map/``, ``sparse.ply``, ``topology.*``: the largest component's merged map (sessions as
  segments); other components in ``components/<i>/``;
* ``trajectories/<name>.txt``: every frame of the session (TUM, ``T_world_cam``) in the common
  frame of its component (the world of its root session: the one with the most keyframes);
* ``sessions.json``: ``sessions`` (``status``, ``error``, ``reused``, ``component``,
  ``S_common_session``), ``overlaps`` (verified edges: ``inliers``, ``S_a_b`` SE(3) / Sim(3),
  ``in_tree``), ``candidates`` (every pair verified, with its index score and outcome),
  ``components`` (lists of names, the largest first), ``component_maps``, ``index`` (keyframes,
  queries, candidate pairs of all pairs), ``timing``; ``stats.json``: the summary.

``vslam map --map OUT NEW...`` adds sessions to an earlier result: the sessions of its
``sessions.json`` are reused (their run folders are complete), the new ones tracked, and the
overlap search and the merges redone over all of them (not incremental yet).

Modules: :mod:`~vslam.multisession.sessions` (inputs, one session's task),
:mod:`~vslam.multisession.executor` (local pool / Ray), :mod:`~vslam.multisession.overlap`
(the index, candidate pairs, pair verification), :mod:`~vslam.multisession.graph`
(components, spanning tree), :mod:`~vslam.multisession.merging` (tree merge, trajectories),
:mod:`~vslam.multisession.pipeline` (:func:`map_sessions`).

Example::

    from vslam.multisession import map_sessions
    result = map_sessions(["sessions.yaml"], "out/building", executor="ray", workers=4)
    print(result["components"])
"""
from __future__ import annotations

from vslam.multisession.pipeline import map_sessions
from vslam.multisession.sessions import SessionSpec, parse_inputs

__all__ = ["SessionSpec", "map_sessions", "parse_inputs"]
