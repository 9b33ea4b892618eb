"""The keyframe database with the packaged vocabulary on real frames: a revisit is retrieved."""
from __future__ import annotations

import pytest

from vslam.map.database import KeyframeDatabase


@pytest.mark.shared
def test_redkitchen_revisit_is_retrieved(redkitchen, vocabulary):
    """7-Scenes: frame 946 returns to frame 248 (1.2 cm); keyframes are every 10th frame 0-900."""
    desc = redkitchen["descriptors"]
    db = KeyframeDatabase(vocabulary.n_words)
    for i in range(0, 901, 10):
        db.add(i, vocabulary.transform(desc[i])[0])
    query = vocabulary.transform(desc[946])[0]
    near = [i for i in db.keyframe_ids if abs(i - 946) <= 30]
    results = db.query(query, 5, exclude_ids=near)
    assert abs(results[0][0] - 248) <= 15, results
    # all of the top three lie on the revisited stretch (frames 230-270)
    assert all(230 <= k <= 270 for k, _ in results[:3]), results
    # a frame in the middle of a stretch finds its temporal neighbours when they are not excluded
    top = db.query(vocabulary.transform(desc[503])[0], 3)
    assert abs(top[0][0] - 503) <= 10, top
    assert all(abs(k - 503) <= 20 for k, _ in top[:2]), top
