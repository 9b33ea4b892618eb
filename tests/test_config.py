from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import pytest

from vslam.config import dump_config, load_config, to_dict
from vslam.errors import ConfigError


@dataclass(frozen=True)
class Inner:
    enabled: bool = True
    motion: Literal["3d2d", "3d3d", "2d2d"] = "3d2d"
    ratio: float = 0.8
    n: int = 10
    levels: tuple[int, ...] = (1, 2)
    name: str | None = None


@dataclass(frozen=True)
class Root:
    inner: Inner = field(default_factory=Inner)
    seed: int = 0


def test_overrides_are_typed():
    cfg = load_config(Root, None, ["inner.enabled=false", "inner.motion=3d3d", "inner.ratio=0.7",
                                   "inner.n=3", "inner.levels=[4, 5, 6]", "seed=7", "inner.name=abc"])
    assert cfg.inner.enabled is False
    assert cfg.inner.motion == "3d3d"
    assert cfg.inner.ratio == pytest.approx(0.7)
    assert cfg.inner.n == 3 and cfg.seed == 7
    assert cfg.inner.levels == (4, 5, 6)
    assert cfg.inner.name == "abc"


@pytest.mark.parametrize("bad, msg", [
    ("inner.enabeld=false", "unknown setting inner.enabeld"),
    ("inner.motion=4d4d", "not one of"),
    ("inner.n=abc", "expected an integer"),
    ("inner.enabled=3", "expected true or false"),
    ("novalue", "key=value"),
])
def test_bad_overrides_name_the_key(bad, msg):
    with pytest.raises(ConfigError, match=msg):
        load_config(Root, None, [bad])


def test_yaml_round_trip(tmp_path):
    cfg = load_config(Root, None, ["inner.ratio=0.5", "inner.levels=[3]"])
    path = tmp_path / "c.yaml"
    dump_config(cfg, path)
    again = load_config(Root, path)
    assert again == cfg
    assert to_dict(again)["inner"]["levels"] == [3]


def test_bad_yaml_file(tmp_path):
    p = tmp_path / "bad.yaml"
    p.write_text("inner: [unclosed")
    with pytest.raises(ConfigError, match="bad.yaml"):
        load_config(Root, p)
    with pytest.raises(ConfigError, match="not found"):
        load_config(Root, tmp_path / "missing.yaml")


def test_dotted_keys_in_a_config_file(tmp_path, capsys):
    """`features.n_features: 1000` (the key form `vslam config` prints) is the nested key; the two
    forms mix; a setting given both ways, an unknown dotted key and `key = value` lines are refused
    in one line."""
    from vslam.cli import main
    from vslam.config import Config

    p = tmp_path / "c.yaml"
    p.write_text("features.n_features: 1000\nfrontend:\n  motion: 3d3d\nfrontend.tracking.max_frames_to_place: 7\n"
                 "loop.enabled: false\n")
    cfg = load_config(Config, p)
    nested = tmp_path / "n.yaml"
    nested.write_text("features: {n_features: 1000}\nfrontend: {motion: 3d3d, tracking: {max_frames_to_place: 7}}\n"
                      "loop: {enabled: false}\n")
    assert cfg == load_config(Config, nested) != Config()
    assert (cfg.features.n_features, cfg.frontend.motion, cfg.frontend.tracking.max_frames_to_place) == (1000, "3d3d", 7)
    assert load_config(Root, None, []) == Root()
    p.write_text("inner.n: 4\nseed: 2\n")
    assert load_config(Root, p) == Root(inner=Inner(n=4), seed=2)
    for text, msg in [("inner.nope: 1\n", "unknown setting inner.nope; valid keys here: enabled, levels"),
                      ("inner: {n: 1}\ninner.n: 2\n", "setting inner.n is given twice"),
                      ("inner: 3\ninner.n: 2\n", "inner is given as a value and inner.n as one of its settings"),
                      ("nope.n: 1\n", "unknown setting nope")]:
        p.write_text(text)
        with pytest.raises(ConfigError, match=msg):
            load_config(Root, p)
    # through the command line: one line, exit 2, before anything runs
    (tmp_path / "pasted.yaml").write_text("features.n_features = 1000   # pasted from `vslam config`\n"
                                          "features.n_levels = 8\n")
    (tmp_path / "unknown.yaml").write_text("features.n_featurez: 1000\n")
    for name, msg in [("pasted.yaml", "write one 'key: value' per line"), ("unknown.yaml", "unknown setting features.n_featurez")]:
        assert main(["run", str(tmp_path), "-o", str(tmp_path / "o"), "--config", str(tmp_path / name)]) == 2
        err = capsys.readouterr().err
        assert msg in err and len(err.strip().splitlines()) == 1
