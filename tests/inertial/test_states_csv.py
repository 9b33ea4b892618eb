"""``imu_states.csv`` (:mod:`vslam.inertial.states_csv`) and its report figure."""
from __future__ import annotations

import numpy as np
import pytest

from vslam.errors import DatasetError
from vslam.inertial.states_csv import COLUMNS, read_imu_states, write_imu_states


def test_round_trip_and_bad_file(tmp_path):
    rows = [[100.0 + 0.05 * k, 0.1 * k, -0.2, 0.3, 1e-3, 2e-3, 3e-3, -0.05, 0.01, 0.04, int(5 <= k < 8)]
            for k in range(12)]
    path = write_imu_states(tmp_path / "imu_states.csv", rows)
    st = read_imu_states(path)
    assert tuple(st) == COLUMNS
    np.testing.assert_allclose(np.column_stack([st[c] for c in COLUMNS]), np.asarray(rows), rtol=1e-8, atol=1e-9)
    (tmp_path / "bad.csv").write_text("1,2,3\n")
    with pytest.raises(DatasetError, match="3 columns, expected 11"):
        read_imu_states(tmp_path / "bad.csv")


def test_report_figure(tmp_path):
    """The report's figure: a PNG data URI from the file; None without one; a broken file is a note."""
    from vslam.report.imu_chart import load_imu_states, plot_imu_states

    rows = [[float(k), np.sin(k), np.cos(k), 0.0, 0, 0, 0, 0, 0, 0, int(k in (3, 4))] for k in range(10)]
    write_imu_states(tmp_path / "imu_states.csv", rows)
    notes: list[str] = []
    assert plot_imu_states(load_imu_states(tmp_path, notes)).startswith("data:image/png;base64,")
    assert plot_imu_states(load_imu_states(tmp_path / "none", notes)) is None and not notes
    (tmp_path / "imu_states.csv").write_text("x\n")
    assert load_imu_states(tmp_path, notes) is None and "imu_states.csv not readable" in notes[0]
