"""KeyframeQueue: inline vs worker thread, newest-only skipping, and a worker that survives errors."""
from __future__ import annotations

import threading

from vslam.map.keyframe_queue import KeyframeQueue


def test_deterministic_mode_runs_inline_in_order():
    done: list[int] = []
    q = KeyframeQueue(done.append, realtime=False, name="t")
    for k in (3, 1, 2):
        q.put(k)
    assert done == []  # nothing runs until the owner says so
    q.run_pending()
    assert done == [3, 1, 2]


def test_realtime_newest_only_skips_what_piled_up():
    done: list[int] = []
    gate = threading.Event()

    def handle(k: int) -> None:
        if k == 0:
            gate.wait(5.0)  # busy on keyframe 0 while 1..4 arrive
        done.append(k)

    q = KeyframeQueue(handle, realtime=True, name="t", newest_only=True)
    q.put(0)
    while not q._queue.empty():  # the worker has taken keyframe 0
        pass
    for k in range(1, 5):
        q.put(k)
    gate.set()
    q.finish()
    assert done == [0, 4] and q.skipped == 3


def test_realtime_worker_survives_an_error_and_handles_every_id():
    done: list[int] = []

    def handle(k: int) -> None:
        if k == 1:
            raise RuntimeError("boom")
        done.append(k)

    q = KeyframeQueue(handle, realtime=True, name="t")
    for k in range(4):
        q.put(k)
    q.finish()
    assert done == [0, 2, 3] and q.failed == 1 and q.skipped == 0
