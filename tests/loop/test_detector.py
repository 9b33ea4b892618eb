"""Temporal-consistency loop detector: logic on synthetic vectors, no false loop on KITTI 07, real loop in 7-Scenes."""
from __future__ import annotations

import numpy as np
import pytest

from vslam.loop.config import DatabaseConfig, LoopDetectorConfig
from vslam.map.database import KeyframeDatabase
from vslam.loop.detector import LoopDetector
from vslam.loop.vocabulary import BowVector

N_WORDS = 8000


def trajectory(path: list[int], seed: int = 0) -> list[BowVector]:
    """BoW vectors of keyframes along ``path`` (a list of places, 400 words each).

    Keyframe ``t`` sees 150 random words of place ``path[t]`` and 150 of the next place on the path,
    so consecutive keyframes overlap as in a real sequence; 10 % of the words are random clutter.
    """
    rng = np.random.default_rng(seed)
    bows = []
    for t, p in enumerate(path):
        seen = [p] if t + 1 == len(path) else [p, path[t + 1]]
        words = np.concatenate([q * 400 + rng.choice(400, 150, replace=False) for q in seen]
                               + [rng.choice(N_WORDS, 30)])
        words = np.unique(words).astype(np.int32)
        values = rng.random(words.size) + 0.5
        bows.append(BowVector(words, values / values.sum()))
    return bows


def run(det: LoopDetector, path: list[int], **kwargs) -> dict:
    accepted = {}
    for kf_id, bow in enumerate(trajectory(path)):
        candidate = det.detect(kf_id, bow, **kwargs)
        if candidate is not None:
            accepted[kf_id] = candidate
    return accepted


def detector(**overrides) -> LoopDetector:
    cfg = LoopDetectorConfig(**{"min_score": 0.5, "min_consistent": 3, "group_radius": 2, "exclude_radius": 2,
                                **overrides})
    return LoopDetector(KeyframeDatabase(N_WORDS, DatabaseConfig(min_baseline_keyframes=4)), cfg)


def test_loop_needs_consecutive_consistent_queries():
    # places 0-11, then back through 2, 3, 4, 5: keyframe 11 already looks into place 2, so the
    # revisit is seen by keyframes 11, 12, 13, ... and is accepted from the third one on
    det = detector()
    accepted = run(det, list(range(12)) + [2, 3, 4, 5])
    assert sorted(accepted) == [13, 14, 15]
    assert [accepted[k].match_id for k in (13, 14)] == [3, 4]
    assert accepted[15].match_id in (4, 5)  # keyframe 15 sees place 5 only, as do keyframes 4 and 5
    assert [accepted[k].consistency for k in (13, 14, 15)] == [3, 4, 5]
    assert len(det.database) == 16


def test_short_revisit_is_not_accepted():
    # only keyframes 11 and 12 see place 2, then new places: consistency 2 < 3
    path = list(range(12)) + [2, 12, 13, 14, 15]
    assert run(detector(), path) == {}
    assert sorted(run(detector(min_consistent=2), path)) == [12]
    assert run(detector(min_score=50.0, min_consistent=1), path) == {}


def test_covisibility_callback_defines_groups():
    covisible = {0: {1}, 1: {0}}
    det = LoopDetector(KeyframeDatabase(N_WORDS, DatabaseConfig(min_baseline_keyframes=4)),
                       LoopDetectorConfig(min_score=0.5, min_consistent=2),
                       neighbours=lambda k: covisible.get(k, set()))
    path = list(range(10)) + [0, 1, 1]
    bows = trajectory(path)
    for kf_id in range(10):  # keyframe 9 looks into place 0: consistency 1
        assert det.detect(kf_id, bows[kf_id], covisible_ids=[kf_id - 1]) is None
    candidate = det.detect(10, bows[10], covisible_ids=[9])
    assert candidate is not None and candidate.match_id in (0, 1) and candidate.consistency == 2
    assert candidate.group <= {0, 1}  # the callback's groups, not the default 20-id radius
    det.reset()
    assert det.detect(11, bows[11], covisible_ids=[10]) is None  # consistency restarts after reset


@pytest.mark.shared
def test_no_loop_on_kitti07(kitti07, vocabulary):
    """KITTI 07 frames 0-158 (every 2nd): 90 m of forward driving, no revisit, so no loop."""
    db = KeyframeDatabase(vocabulary.n_words)
    det = LoopDetector(db, LoopDetectorConfig())
    accepted, best = [], 0.0
    for i, desc in kitti07["descriptors"].items():
        bow = vocabulary.transform(desc)[0]
        near = [k for k in db.keyframe_ids if abs(k - i) <= det.config.exclude_radius]
        if len(db) - len(near) >= db.config.min_baseline_keyframes:
            best = max([best] + [s for _, s in db.query(bow, 1, exclude_ids=near)])
        if (candidate := det.detect(i, bow)) is not None:
            accepted.append(candidate)
    assert accepted == []
    assert best < 0.8 * det.config.min_score, f"best normalized candidate score {best:.2f}"


@pytest.mark.shared
def test_redkitchen_loop_is_detected(redkitchen, vocabulary):
    """7-Scenes, every 10th frame: the return to frame 248 at ~946 is accepted; every accepted loop is real."""
    desc, T_world_cam = redkitchen["descriptors"], redkitchen["T_world_cam"]
    det = LoopDetector(KeyframeDatabase(vocabulary.n_words), LoopDetectorConfig())
    accepted = [c for i in range(0, 1000, 10) if (c := det.detect(i, vocabulary.transform(desc[i])[0]))]
    assert any(abs(c.match_id - 248) <= 15 and 930 <= c.query_id <= 960 for c in accepted), accepted
    # every accepted pair views the same part of the kitchen: < 0.5 m and < 30 deg apart
    for c in accepted:
        T_a, T_b = T_world_cam[c.query_id], T_world_cam[c.match_id]
        cos = (np.trace(T_a[:3, :3].T @ T_b[:3, :3]) - 1) / 2
        distance, angle = np.linalg.norm(T_a[:3, 3] - T_b[:3, 3]), np.degrees(np.arccos(np.clip(cos, -1, 1)))
        assert distance < 0.5 and angle < 30, (c.query_id, c.match_id, distance, angle)
