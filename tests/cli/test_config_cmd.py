"""``vslam config``: every setting with its default and doc; docs/settings.md generated from the same source."""
from __future__ import annotations

import dataclasses
import logging
from pathlib import Path

import pytest

from vslam.backend.config import BackendConfig
from vslam.cli import main
from vslam.config import Config, dump_config, flat_key_map, iter_settings, load_config, settings_markdown
from vslam.errors import ConfigError
from vslam.features.config import KLTConfig, MatcherConfig

SETTINGS_MD = Path(__file__).resolve().parents[2] / "docs" / "settings.md"


def _classes(cls: type) -> list[type]:
    out = [cls]
    for f in dataclasses.fields(cls):
        if isinstance(f.default_factory, type) and dataclasses.is_dataclass(f.default_factory):
            out += _classes(f.default_factory)
    return out


def test_settings_md_is_up_to_date():
    assert SETTINGS_MD.read_text() == settings_markdown(Config), (
        "docs/settings.md is stale: regenerate it with `vslam config --markdown > docs/settings.md`")


@pytest.mark.parametrize("cls", _classes(Config) + [MatcherConfig, KLTConfig], ids=lambda c: c.__name__)
def test_every_field_has_a_one_line_doc(cls):
    for f in dataclasses.fields(cls):
        doc = f.metadata.get("doc", "")
        assert doc.strip(), f"{cls.__name__}.{f.name} has no doc (declare it with vslam.param.param)"
        assert "\n" not in doc, f"{cls.__name__}.{f.name}: the doc must be one line"


def test_settings_tree():
    keys = [s.key for s in iter_settings(Config)]
    assert len(keys) == len(set(keys)) >= 177
    for key in ("frontend.keyframes.max_frames", "frontend.tracking.min_inliers", "frontend.dense.refine",
                "backend.local.chi2_mono", "loop.closing.min_inliers", "features.n_features",
                "backend.fusion.radius_px", "backend.cull.age_keyframes", "loop.closing.confirm.max_deg",
                "localize.min_inliers", "localize.reloc_min_inliers"):
        assert key in keys
    # `vslam localize --set localize.KEY=...` goes through the root Config
    assert load_config(Config, None, ["localize.min_inliers=25"]).localize.min_inliers == 25


def test_cli_prints_keys_defaults_and_docs(capsys):
    assert main(["config"]) == 0
    out = capsys.readouterr().out
    assert len(out.splitlines()) == len(iter_settings(Config))
    assert "frontend.keyframes.max_frames = 20  " in out and "insert a keyframe at least every" in out
    assert "backend.ekf.gate_chi2 = .inf" in out
    assert main(["config", "frontend.init"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 13 and all(line.startswith("frontend.init.") for line in lines)
    assert main(["config", "--markdown"]) == 0
    assert capsys.readouterr().out == SETTINGS_MD.read_text()
    assert main(["config", "frontend.nope"]) == 2


def test_nested_set_and_yaml(tmp_path):
    cfg = load_config(Config, None, ["frontend.keyframes.min_frames=5", "frontend.dense.refine=false"])
    assert cfg.frontend.keyframes.min_frames == 5 and cfg.frontend.dense.refine is False
    path = tmp_path / "c.yaml"
    path.write_text("frontend:\n  tracking:\n    min_inliers: 30\n  klt:\n    window: 21\n")
    cfg = load_config(Config, path)
    assert cfg.frontend.tracking.min_inliers == 30 and cfg.frontend.klt.window == 21
    assert cfg.frontend.keyframes == Config().frontend.keyframes
    dump_config(cfg, tmp_path / "again.yaml")
    assert load_config(Config, tmp_path / "again.yaml") == cfg
    with pytest.raises(ConfigError, match=r"frontend.tracking.min_inliers=3 is out of range: valid values are \[6, "):
        load_config(Config, None, ["frontend.tracking.min_inliers=3"])
    with pytest.raises(ConfigError, match="unknown setting frontend.keyframes.max_frame"):
        load_config(Config, None, ["frontend.keyframes.max_frame=3"])


def test_old_flat_keys_map_to_nested_ones_with_a_warning(caplog, tmp_path):
    mapping = flat_key_map(type(Config().frontend))
    assert mapping["kf_max_frames"] == ("keyframes", "max_frames")
    assert mapping["depth_refine_downsample"] == ("dense", "refine_downsample")
    assert mapping["dense_links"] == ("dense", "links")
    assert mapping["local_keyframes"] == ("local_map", "keyframes")
    assert mapping["max_lost_frames"] == ("tracking", "max_lost_frames")
    with caplog.at_level(logging.WARNING):
        cfg = load_config(Config, None, ["frontend.kf_max_frames=7", "frontend.dense_links=false"])
    assert cfg.frontend.keyframes.max_frames == 7 and cfg.frontend.dense.links is False
    assert "frontend.kf_max_frames is deprecated; use frontend.keyframes.max_frames" in caplog.text
    path = tmp_path / "old.yaml"
    path.write_text("frontend:\n  init_min_matches: 90\n  init:\n    max_frames: 12\n")
    cfg = load_config(Config, path)
    assert cfg.frontend.init.min_matches == 90 and cfg.frontend.init.max_frames == 12
    # the backend's and loop closing's flat groups (an old key without the common prefix: flat_keys)
    backend = flat_key_map(BackendConfig)
    assert backend["fuse"] == ("fusion", "enabled") and backend["fuse_radius_px"] == ("fusion", "radius_px")
    assert backend["fuse_mono"] == ("fusion", "mono") and backend["mono_left_out"] == ("mono", "left_out")
    assert backend["cull_keyframes"] == ("cull", "keyframes") and backend["redundant_ratio"] == ("cull", "redundant_ratio")
    closing = flat_key_map(type(Config().loop.closing))
    assert closing["confirm_max_deg"] == ("confirm", "max_deg") and closing["fuse_ratio"] == ("fuse", "ratio")
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        cfg = load_config(Config, None, ["backend.fuse=false", "backend.mono_min_observations=2",
                                         "backend.cull_age_keyframes=4", "loop.closing.confirm_min_inliers=20"])
    assert cfg.backend.fusion.enabled is False and cfg.backend.mono.min_observations == 2
    assert cfg.backend.cull.age_keyframes == 4 and cfg.loop.closing.confirm.min_inliers == 20
    assert "backend.fuse is deprecated; use backend.fusion.enabled" in caplog.text
    with pytest.raises(ConfigError, match="mono.min_observations must be >= 2"):
        load_config(Config, None, ["backend.mono.min_observations=1"])
