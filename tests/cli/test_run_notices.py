"""What `vslam run` says on a first run (issue #25, items 4 and 5): one line before the numeric
kernels compile, and `--viz rerun` on a machine without a display (said at the start, the run goes
on, and a viewer failure after the outputs are written is a warning with exit 0)."""
from __future__ import annotations

import json
import logging

import pytest

import vslam.stream as stream
from vslam.cli import main
from vslam.cli.common import COMPILE_NOTICE


@pytest.fixture
def fr1(shared_data):
    return shared_data / "tum_rgbd_freiburg1_desk_9frames"


def test_compile_notice_on_a_cold_cache_only(fr1, tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(stream, "kernels_cold", lambda modules=stream.KERNEL_MODULES: True)
    assert main(["run", str(fr1), "-o", str(tmp_path / "cold"), "--no-progress"]) == 0
    out = capsys.readouterr()
    assert out.err.count(COMPILE_NOTICE) == 1 and COMPILE_NOTICE not in out.out
    stats = json.loads((tmp_path / "cold" / "stats.json").read_text())
    assert stats["startup_ms"]["kernels"] > 0  # the warm-up is start-up time, outside wall_s and fps
    assert stats["fps"] == pytest.approx(stats["frames"] / stats["wall_s"], rel=0.01)
    # bad input fails before any tracker is built: no promise of a compile that never comes
    bad = tmp_path / "bad.yaml"
    bad.write_text("features.nope: 3\n")
    assert main(["run", str(fr1), "-o", str(tmp_path / "bad"), "--config", str(bad)]) == 2
    assert COMPILE_NOTICE not in capsys.readouterr().err
    monkeypatch.setattr(stream, "kernels_cold", lambda modules=stream.KERNEL_MODULES: False)
    assert main(["run", str(fr1), "-o", str(tmp_path / "warm"), "--no-progress"]) == 0
    assert COMPILE_NOTICE not in capsys.readouterr().err


@pytest.fixture
def rerun_sdk(monkeypatch):
    rr = pytest.importorskip("rerun", reason="rerun-sdk not installed (pip install 'vslam[viz]'); CI installs it")
    for var, value in (("RERUN_TELEMETRY", "0"), ("TELEMETRY_ENABLED", "false"), ("RERUN_ANALYTICS", "0")):
        monkeypatch.setenv(var, value)
    return rr


def test_viz_rerun_without_a_display_says_so_and_runs(fr1, tmp_path, capsys, caplog, monkeypatch, rerun_sdk):
    from vslam.viz import rerun_viewer

    monkeypatch.setattr(rerun_viewer.sys, "platform", "linux")
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    spawned = []
    monkeypatch.setattr(rerun_sdk, "spawn", lambda **kw: spawned.append(kw))
    from vslam.system import System

    track, said_before_first_frame = System.track, []

    def tracking(self, frame):  # notes whether the warning was out before the first frame
        if not said_before_first_frame:
            said_before_first_frame.append(any("--viz rerun" in r.getMessage() for r in caplog.records))
        return track(self, frame)

    monkeypatch.setattr(System, "track", tracking)
    with caplog.at_level(logging.WARNING):
        rc = main(["run", str(fr1), "-o", str(tmp_path / "out"), "--no-progress", "--viz", "rerun"])
    assert rc == 0 and not spawned
    warned = [r.getMessage() for r in caplog.records if "--viz rerun" in r.getMessage()]
    assert len(warned) == 1 and "no display" in warned[0] and "--viz rerun:FILE.rrd" in warned[0]
    assert "running without a viewer" in warned[0]
    assert said_before_first_frame == [True]
    assert json.loads((tmp_path / "out" / "stats.json").read_text())["tracked"] == 9
    assert "9/9 frames tracked" in capsys.readouterr().out


def test_a_viewer_that_fails_at_the_end_is_a_warning(fr1, tmp_path, capsys, caplog, monkeypatch, rerun_sdk):
    """The viewer started (a desktop) but its connection breaks: the finished run exits 0."""
    from vslam.viz import rerun_viewer

    monkeypatch.setenv("DISPLAY", ":99")
    monkeypatch.setattr(rerun_viewer.RerunViewer, "_spawn", lambda self, rr: None)

    def broken(self, *args, **kwargs):
        raise RuntimeError("gRPC: transport error, connection refused")

    monkeypatch.setattr(rerun_sdk.RecordingStream, "flush", broken)
    with caplog.at_level(logging.WARNING):
        rc = main(["run", str(fr1), "-o", str(tmp_path / "out"), "--no-progress", "--viz", "rerun", "--max-frames", "5"])
    err = capsys.readouterr().err
    assert rc == 0 and "internal error" not in err
    assert any("could not be closed cleanly" in r.getMessage() and "gRPC" in r.getMessage() for r in caplog.records)
    stats = json.loads((tmp_path / "out" / "stats.json").read_text())
    assert stats["frames"] == 5 and "error" not in stats and (tmp_path / "out" / "map").is_dir()


def test_no_display_reason():
    from vslam.viz.rerun_viewer import no_display_reason

    assert "DISPLAY" in no_display_reason({}, "linux")
    assert no_display_reason({"DISPLAY": ":0"}, "linux") is None
    assert no_display_reason({"WAYLAND_DISPLAY": "wayland-0"}, "linux") is None
    assert no_display_reason({}, "darwin") is None and no_display_reason({}, "win32") is None
