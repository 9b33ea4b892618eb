"""Background decoding keeps the reader's order, skipping, errors and a bounded lookahead."""
from __future__ import annotations

import logging
import threading
import time

import pytest

from vslam.datasets import open_dataset
from vslam.datasets.prefetch import BALANCE_LEAD, prefetch
from vslam.errors import DatasetError


def _rgb(root, i):
    return sorted((root / "rgb").iterdir())[i]


def _prefetch_threads() -> list[threading.Thread]:
    return [t for t in threading.enumerate() if t.name == "vslam-prefetch"]


def test_same_frames_in_the_same_order(tmp_path, make_tum):
    root = make_tum(tmp_path / "seq", n=12)
    ds = open_dataset(root)
    plain = [(f.index, f.timestamp, f.image.sum(), f.depth.sum()) for f in ds.frames(2, 11)]
    fetched = [(f.index, f.timestamp, f.image.sum(), f.depth.sum()) for f in prefetch(ds.frames(2, 11), depth=3)]
    assert fetched == plain and len(fetched) == 9


def test_corrupt_frame_is_still_skipped_and_counted(tmp_path, make_tum, caplog):
    root = make_tum(tmp_path / "seq", n=12)
    _rgb(root, 5).write_bytes(b"this is not a png")
    ds = open_dataset(root)
    with caplog.at_level(logging.WARNING, logger="vslam.datasets"):
        frames = list(prefetch(ds.frames(), depth=4))
    assert len(frames) == 11 and ds.skipped == 1
    assert 5 not in [f.index for f in frames]
    assert any("skipping frame 5" in r.getMessage() for r in caplog.records)


def test_reader_error_arrives_after_the_frames_before_it(tmp_path, make_tum):
    root = make_tum(tmp_path / "seq", n=12)
    for i in (3, 6):  # the second failure passes 10% of 12 frames: raises at frame 6
        _rgb(root, i).write_bytes(b"garbage")
    ds = open_dataset(root)
    seen = []
    with pytest.raises(DatasetError, match="2 of 12 frames failed to decode"):
        for f in prefetch(ds.frames(), depth=8):
            seen.append(f.index)
    assert seen == [0, 1, 2, 4, 5]


def test_lookahead_is_bounded_and_early_exit_stops_the_thread():
    produced = []

    def source():
        for i in range(1000):
            produced.append(i)
            yield i

    it = prefetch(source(), depth=3)
    assert next(it) == 0
    time.sleep(0.3)  # let the producer run ahead as far as it may
    # one consumed, 3 waiting in the queue, at most one more decoded and blocked on the full queue
    assert len(produced) <= 1 + 3 + 1
    it.close()
    deadline = time.monotonic() + 3.0
    while _prefetch_threads() and time.monotonic() < deadline:
        time.sleep(0.02)
    assert not _prefetch_threads()
    assert len(produced) <= 6


def test_depth_zero_is_the_plain_iterator():
    assert list(prefetch(iter(range(5)), depth=0)) == [0, 1, 2, 3, 4]
    assert not _prefetch_threads()


def test_prepare_runs_in_the_thread_and_its_errors_arrive_in_order():
    seen = {}

    def prepare(i):
        if i == 4:
            raise ValueError("bad item 4")
        seen[i] = threading.current_thread().name

    out = []
    with pytest.raises(ValueError, match="bad item 4"):
        for i in prefetch(iter(range(10)), depth=2, prepare=prepare, balance=False):
            out.append(i)
    assert out == [0, 1, 2, 3]
    assert set(seen) == {0, 1, 2, 3} and set(seen.values()) == {"vslam-prefetch"}


def test_balanced_prepare_works_ahead_only_while_the_consumer_is_busy():
    prepared = []
    items = []
    for i in prefetch(iter(range(8)), depth=3, prepare=prepared.append):
        time.sleep(0.03)  # a slow consumer: the queue fills, so the thread prepares
        items.append(i)
    assert items == list(range(8))
    # the first items go out raw while BALANCE_LEAD items fill the queue, all later ones prepared
    assert len(prepared) >= 8 - BALANCE_LEAD - 1 and prepared == sorted(prepared)
    prepared.clear()
    slow = (time.sleep(0.03) or i for i in range(4))  # a slow producer: the consumer waits, no prepare
    assert list(prefetch(slow, depth=3, prepare=prepared.append)) == [0, 1, 2, 3]
    assert prepared == []
