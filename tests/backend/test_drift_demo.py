"""The drift demonstration writes its plot and shows the loop closure's effect in numbers."""
from __future__ import annotations

import pytest

from vslam.backend.drift_demo import run_drift_demo
from vslam.errors import ConfigError


def test_drift_demo_numbers_and_plot(tmp_path):
    out = run_drift_demo(tmp_path, noise=1.0, seed=0)
    png = tmp_path / "drift_demo.png"
    assert png.is_file() and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert out["plot"] == str(png)
    assert out["end_drift_before"] > 1.0  # measured 3.3 m after 62 m
    assert out["end_drift_after"] < 0.01 * out["end_drift_before"]
    assert out["ate_after"] < out["ate_before"] / 5.0  # measured 1.01 -> 0.022 m
    assert 60 < out["path_length"] < 64  # a 10 m radius circle


def test_more_noise_more_drift(tmp_path):
    low = run_drift_demo(tmp_path / "a", noise=0.5, seed=1)
    high = run_drift_demo(tmp_path / "b", noise=2.0, seed=1)
    assert high["ate_before"] > 2 * low["ate_before"]


def test_bad_noise_level(tmp_path):
    with pytest.raises(ConfigError):
        run_drift_demo(tmp_path, noise=-1.0)
