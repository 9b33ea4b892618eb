"""The report's stage-time chart keeps per-keyframe costs (local BA) apart from per-frame ones."""
from __future__ import annotations

from vslam.report.html import plot_stages, split_stage_times


def test_local_ba_is_per_keyframe():
    stats = {"stage_ms": {"features": 9.5, "tracking": 12.0, "local_ba": 160.0, "total": 27.0}}
    per_frame, per_kf = split_stage_times(stats)
    assert per_frame == {"features": 9.5, "tracking": 12.0} and per_kf == {"local_ba": 160.0}
    assert plot_stages(stats).startswith("data:image/png")
    assert split_stage_times({}) == ({}, {}) and plot_stages({}) is None


def _title_total_and_blue_bars(stats: dict) -> tuple[float, list[float], list[str]]:
    """The number in the drawn chart's title and the widths and labels of its blue (tracking) bars."""
    import re

    from matplotlib.colors import to_hex

    from vslam.report.charts import stages_figure

    fig = stages_figure(stats)
    ax = fig.axes[0]
    total = float(re.search(r"tracking ([0-9.]+) ms/frame \(sum of the blue bars\)", ax.get_title()).group(1))
    labels = [t.get_text() for t in ax.get_yticklabels()]
    blue = [(p.get_width(), labels[i]) for i, p in enumerate(ax.patches) if to_hex(p.get_facecolor()) == "#6baed6"]
    return total, [w for w, _ in blue], [l for _, l in blue]


def test_title_total_is_the_sum_of_the_tracking_bars():
    """The bars of the tracking thread add up to the title's total: the time no stage timer
    covers is an "other" bar; local BA (per keyframe) and prepare (another thread) are apart."""
    import pytest

    stats = {"stage_ms": {"features": 9.5, "association": 4.25, "pose": 3.0, "mapping": 2.0, "prepare": 6.0,
                          "local_ba": 160.0, "total": 27.0}}
    total, widths, labels = _title_total_and_blue_bars(stats)
    assert total == pytest.approx(27.0)
    assert sum(widths) == pytest.approx(total, abs=0.05)  # the title prints one decimal
    assert "other (untimed)" in labels and widths[labels.index("other (untimed)")] == pytest.approx(8.25)
    assert "local_ba" not in " ".join(labels) and "prepare" not in " ".join(labels)
    # stages that already add up to the total: no "other" bar; the sum still matches
    stats = {"stage_ms": {"features": 4.0, "tracking": 3.0, "mapping": 2.5, "total": 9.5}}
    total, widths, labels = _title_total_and_blue_bars(stats)
    assert "other (untimed)" not in labels and total == pytest.approx(sum(widths)) == pytest.approx(9.5)
    # a real run's stats.json (vslam/system.py: the stages, prepare, total, local BA per call)
    stats = {"stage_ms": {"features": 12.345, "association": 5.1, "pose": 7.777, "mapping": 3.2, "prepare": 0.0,
                          "total": 31.419, "local_ba": 88.0}}
    total, widths, labels = _title_total_and_blue_bars(stats)
    assert sum(widths) == pytest.approx(total, abs=0.05) and total == pytest.approx(31.4)
