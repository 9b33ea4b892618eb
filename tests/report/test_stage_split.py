"""The report's stage-time chart keeps per-keyframe costs (local BA) apart from per-frame ones."""
from __future__ import annotations

from vslam.report.html import plot_stages, split_stage_times


def test_local_ba_is_per_keyframe():
    stats = {"stage_ms": {"features": 9.5, "tracking": 12.0, "local_ba": 160.0, "total": 27.0}}
    per_frame, per_kf = split_stage_times(stats)
    assert per_frame == {"features": 9.5, "tracking": 12.0} and per_kf == {"local_ba": 160.0}
    assert plot_stages(stats).startswith("data:image/png")
    assert split_stage_times({}) == ({}, {}) and plot_stages({}) is None
