"""What README promises about repeated runs: on one machine with one set of library versions, the
default (deterministic) pipeline writes the same trajectory, byte for byte, whether the run is
repeated in the same process or in a fresh one. (Across machines, BLAS kernels and numba targets
the figures agree within the bands of ``tests/test_pinned_figures.py`` instead.)

Two sequences cover every stage a trajectory depends on: KITTI 06 stereo (stereo matching and
its disparity refinement, PnP, local BA) and EuRoC MH_01 mono (two-view initialization,
triangulation, the monocular BA and its re-triangulation). Both sides of each comparison run the
same code on the same machine, so bit equality is the right test here.
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from vslam.api import run_path

pytestmark = pytest.mark.shared

CASES = {"kitti06-stereo": ("kitti_odometry/sequences/06", "stereo"), "mh01-mono": ("euroc_mh01_vi_80", "mono")}

_CHILD = """
import sys
from vslam.api import run_path
run_path(sys.argv[1], sys.argv[2], sensor=sys.argv[3], prefetch="none")
"""


@pytest.mark.parametrize("case", sorted(CASES))
def test_repeated_runs_write_identical_trajectories(case, shared_data, tmp_path):
    folder, sensor = CASES[case]
    data = shared_data / folder
    outs = [tmp_path / f"in{i}" for i in range(2)]
    for out in outs:  # twice in this process (kernels, caches and the vocabulary already loaded)
        run_path(data, out, sensor=sensor, prefetch="none")
    procs = []
    for i in range(2):  # twice in fresh interpreters, side by side
        out = tmp_path / f"proc{i}"
        outs.append(out)
        procs.append(subprocess.Popen([sys.executable, "-c", _CHILD, str(data), str(out), sensor],
                                      stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True))
    for p in procs:
        log, _ = p.communicate(timeout=600)
        assert p.returncode == 0, log[-2000:]
    files = [Path(o) / "trajectory.txt" for o in outs]
    first = files[0].read_bytes()
    assert first.count(b"\n") >= 40  # a real trajectory (51 / 80 poses), not an empty file
    for f in files[1:]:
        assert f.read_bytes() == first, f"{f} differs from {files[0]}"
    kf = [(Path(o) / "keyframes.txt").read_bytes() for o in outs]
    assert all(k == kf[0] for k in kf[1:])
