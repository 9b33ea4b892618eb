"""Loop candidate detection with temporal consistency.

Follows ORB-SLAM's ``LoopClosing::DetectLoop`` (Mur-Artal et al., T-RO 2015, sec. VII-A), itself a
refinement of DBoW2's temporal consistency (Galvez-Lopez & Tardos 2012, sec. VI-B/C):

1. query the keyframe database, excluding the query's covisible (or temporally near) keyframes;
   scores are normalized by the query's score against those excluded keyframes;
2. each candidate forms a *group* with its neighbours (covisible keyframes, or keyframes with
   nearby ids); a group's score accumulates the scores of the candidates it holds, and groups
   below ``accumulated_ratio`` of the best are dropped (DBoW2's "islands");
3. a group is *consistent* with a group of the previous query when they share a keyframe; its
   consistency counter then grows by one, otherwise it restarts at 1. A group seen in
   ``min_consistent`` consecutive queries is accepted as a loop candidate, to be verified
   geometrically by the caller.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Callable, Iterable

import numpy as np

from vslam.loop.config import LoopDetectorConfig
from vslam.map.database import KeyframeDatabase
from vslam.loop.vocabulary import BowVector

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class LoopCandidate:
    """An accepted loop candidate.

    Attributes:
        query_id: the keyframe that closes the loop.
        match_id: the best-scoring keyframe of the accepted group.
        score: normalized score of ``match_id``.
        group: ids of the accepted group (the match and its neighbours).
        consistency: consecutive queries the group was found in.
    """

    query_id: int
    match_id: int
    score: float
    group: frozenset[int]
    consistency: int


class LoopDetector:
    """Feeds keyframes to a :class:`KeyframeDatabase` and reports temporally consistent loops.

    Args:
        database: the keyframe database (the detector adds each processed keyframe to it).
        config: thresholds.
        neighbours: ``kf_id -> ids`` of a keyframe's covisible keyframes (from the map); by default
            keyframes whose ids are within ``config.group_radius`` (ids in temporal order).

    Attributes:
        last_best: the best-scoring group of the last query whatever its consistency (None when no
            group passed); the loop closer may verify it as a single detection (ORB-SLAM3-style).
    """

    def __init__(self, database: KeyframeDatabase, config: LoopDetectorConfig = LoopDetectorConfig(),
                 neighbours: Callable[[int], Iterable[int]] | None = None) -> None:
        self.database = database
        self.config = config
        self._neighbours = neighbours
        self._groups: list[tuple[frozenset[int], int]] = []
        self.last_best: LoopCandidate | None = None

    def reset(self) -> None:
        """Forget the consistency groups (e.g. after a loop was closed or rejected)."""
        self._groups = []

    def _group_of(self, kf_id: int, db_ids: np.ndarray) -> frozenset[int]:
        if self._neighbours is not None:
            return frozenset({kf_id, *map(int, self._neighbours(kf_id))})
        near = db_ids[np.abs(db_ids - kf_id) <= self.config.group_radius]
        return frozenset({kf_id, *near.tolist()})

    def detect(self, kf_id: int, bow: BowVector, covisible_ids: Iterable[int] | None = None,
               add: bool = True) -> LoopCandidate | None:
        """Process one new keyframe; returns the accepted loop candidate or None.

        Args:
            kf_id: the new keyframe's id.
            bow: its BoW vector.
            covisible_ids: keyframes connected to it in the map; excluded from the query. By
                default the database keyframes with ids within ``config.exclude_radius``.
            add: add the keyframe to the database after the query.
        """
        cfg = self.config
        kf_id = int(kf_id)
        db_ids = np.array(self.database.keyframe_ids, dtype=np.int64)
        if covisible_ids is None:
            exclude = set(db_ids[np.abs(db_ids - kf_id) <= cfg.exclude_radius].tolist())
        else:
            exclude = {int(i) for i in covisible_ids}
        exclude.add(kf_id)
        candidates = self.database.query(bow, cfg.max_candidates, exclude, min_score=cfg.min_score)
        accepted: LoopCandidate | None = None
        self.last_best = None  # the best group of this query whatever its consistency (see LoopCloser)
        current: list[tuple[frozenset[int], int]] = []
        if candidates:
            scores = dict(candidates)
            groups = []
            for cand_id, _ in candidates:
                group = self._group_of(cand_id, db_ids) - exclude
                members = [i for i in group if i in scores]
                accumulated = sum(scores[i] for i in members)
                best = max(members, key=lambda i: (scores[i], -i))
                groups.append((group, accumulated, best))
            best_accumulated = max(g[1] for g in groups)
            for group, accumulated, best in groups:
                if accumulated < cfg.accumulated_ratio * best_accumulated:
                    continue
                consistency = 1
                for previous, count in self._groups:
                    if group & previous:
                        consistency = max(consistency, count + 1)
                current.append((group, consistency))
                if self.last_best is None or scores[best] > self.last_best.score:
                    self.last_best = LoopCandidate(kf_id, best, scores[best], group, consistency)
                if consistency >= cfg.min_consistent and (accepted is None or scores[best] > accepted.score):
                    accepted = LoopCandidate(kf_id, best, scores[best], group, consistency)
        self._groups = current
        if accepted is not None:
            log.info("loop candidate: keyframe %d <-> %d (score %.3f, consistent over %d queries)",
                     accepted.query_id, accepted.match_id, accepted.score, accepted.consistency)
        if add:
            self.database.add(kf_id, bow)
        return accepted
