"""Benchmark spec parsing: path resolution, env vars, overrides, defaults and the error messages."""
from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from vslam.bench.spec import load_spec, parse_spec, select_runs
from vslam.errors import ConfigError

REPO = Path(__file__).resolve().parents[2]


def write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "specs" / "bench.yaml"
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(text)
    return p


def test_relative_paths_resolve_against_the_spec_folder(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # the working directory must not matter
    monkeypatch.setenv("SEQ_ROOT", "/data/seqs")
    monkeypatch.delenv("NOT_SET_ANYWHERE", raising=False)
    spec = load_spec(write(tmp_path, """
repeats: 3
defaults: {max_frames: 50, set: {a.b: 1}}
runs:
  - name: one
    data: ../seq/06
    sensor: stereo
    set: {loop.enabled: false, frontend.motion: 3d3d, x.list: [1, 2]}
  - name: two.b-c_d
    data: ${SEQ_ROOT}/tum
    repeats: 1
    start_frame: 4
    max_frames: 9
  - name: three
    data: ${NOT_SET_ANYWHERE:-rel/def}/x
    set: ["k=v"]
"""), check_config=False)
    assert spec.repeats == 3 and spec.n_jobs == 3 + 1 + 3
    one, two, three = spec.runs
    assert one.data == tmp_path / "seq" / "06"
    assert one.sensor == "stereo" and one.max_frames == 50 and one.repeats == 3
    assert one.overrides == ("a.b=1", "loop.enabled=false", 'frontend.motion="3d3d"', "x.list=[1, 2]")
    # overrides are YAML-parsable back to the same values
    assert [yaml.safe_load(o.split("=", 1)[1]) for o in one.overrides] == [1, False, "3d3d", [1, 2]]
    assert two.data == Path("/data/seqs/tum") and two.repeats == 1 and two.start_frame == 4 and two.max_frames == 9
    assert two.sensor is None and two.overrides == ("a.b=1",)
    assert three.data == tmp_path / "specs" / "rel" / "def" / "x"
    assert three.overrides == ("a.b=1", "k=v")


@pytest.mark.parametrize("text, message", [
    ("runs: []", "non-empty list"),
    ("repeat: 2\nruns: [{name: a, data: x}]", "unknown key(s) 'repeat'"),
    ("runs: [{name: a, data: x, sensr: mono}]", "unknown key(s) 'sensr'"),
    ("runs: [{name: a, data: x}, {name: a, data: y}]", "duplicate name"),
    ("runs: [{name: a, data: x, sensor: lidar}]", "'lidar' is not one of mono, stereo, rgbd"),
    ("runs: [{name: a}]", "missing 'data'"),
    ("runs: [{name: 'a b', data: x}]", "name must be"),
    ("repeats: 0\nruns: [{name: a, data: x}]", "repeats: must be >= 1"),
    ("runs: [{name: a, data: x, max_frames: ten}]", "max_frames: expected an integer"),
    ("runs: [{name: a, data: '${VSLAM_TEST_UNSET_VAR}/x'}]", "$VSLAM_TEST_UNSET_VAR"),
    ("runs: [{name: a, data: x, set: [novalue]}]", "'key=value'"),
    ("- just a list", "expected a mapping"),
    ("runs: [{name: a, data: x}", "not valid YAML"),
])
def test_bad_specs_name_the_problem(tmp_path, monkeypatch, text, message):
    monkeypatch.delenv("VSLAM_TEST_UNSET_VAR", raising=False)
    path = write(tmp_path, text)
    with pytest.raises(ConfigError) as err:
        load_spec(path, check_config=False)
    assert message in str(err.value)
    assert str(path) in str(err.value)


def test_check_paths_reports_missing_data(tmp_path):
    (tmp_path / "specs" / "there").mkdir(parents=True)
    path = write(tmp_path, "runs: [{name: ok, data: there}, {name: gone, data: nowhere}]")
    with pytest.raises(ConfigError, match=r"run 'gone'\.data: .*nowhere does not exist"):
        load_spec(path, check_paths=True, check_config=False)


def test_select_runs(tmp_path):
    spec = parse_spec({"runs": [{"name": "a", "data": "x"}, {"name": "b", "data": "y"}]}, tmp_path, check_config=False)
    assert [r.name for r in select_runs(spec, ["b"]).runs] == ["b"]
    with pytest.raises(ConfigError, match="no run named 'c'"):
        select_runs(spec, ["c"])


def test_config_typos_fail_before_running(tmp_path):
    """With the root Config available, a wrong ``set`` key is a ConfigError at load time."""
    config = pytest.importorskip("vslam.config")
    if not hasattr(config, "Config"):
        pytest.skip("vslam.config.Config does not exist yet")
    with pytest.raises(ConfigError, match="run 'a'"):
        parse_spec({"runs": [{"name": "a", "data": "x", "set": {"no_such_stage.field": 1}}]}, tmp_path)


def test_shipped_specs_cover_every_shared_sequence(shared_data, monkeypatch):
    monkeypatch.setenv("VSLAM_SHARED_DATA", str(shared_data))
    spec = load_spec(REPO / "benchmarks" / "all.yaml", check_paths=True)
    got = {(r.data.relative_to(shared_data).as_posix(), r.sensor) for r in spec.runs}
    assert got == {
        ("7scenes_redkitchen", "rgbd"), ("tum_fr3_cabinet_keyframes58", "rgbd"),
        ("tum_rgbd_freiburg1_desk_9frames", "rgbd"), ("kitti_odometry/sequences/06", "stereo"),
        ("kitti_odometry/sequences/07", "mono"), ("euroc_V1_01_easy_40frames", "stereo"),
        ("7scenes_redkitchen", "mono"), ("euroc_mh01_vi_80", "stereo"), ("euroc_mh01_vi_80", "mono"),
    }
    starts = load_spec(REPO / "benchmarks" / "mono_starts.yaml", check_paths=True)
    assert {r.sensor for r in starts.runs} == {"mono"} and len(starts.runs) == 10 and starts.runs[1].start_frame == 3
    smoke = load_spec(REPO / "benchmarks" / "smoke.yaml", check_paths=True)
    assert 1 <= len(smoke.runs) <= 4 and smoke.n_jobs <= 8


def test_inertial_sensors_are_accepted(tmp_path):
    spec = parse_spec({"runs": [{"name": "vi", "data": str(tmp_path), "sensor": "mono-inertial"}]}, tmp_path)
    assert spec.runs[0].sensor == "mono-inertial"
    with pytest.raises(ConfigError, match="stereo-inertial"):  # the message lists the inertial ones too
        parse_spec({"runs": [{"name": "x", "data": str(tmp_path), "sensor": "lidar"}]}, tmp_path)
    vi = load_spec(REPO / "benchmarks" / "inertial.yaml")
    assert {r.sensor for r in vi.runs} == {"stereo", "stereo-inertial", "mono", "mono-inertial"}
