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
