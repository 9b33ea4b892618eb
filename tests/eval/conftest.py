"""Fixtures for the evaluation tests: evo (GPL, test oracle only) imported with HOME in tmp."""
from __future__ import annotations

import importlib

import pytest


@pytest.fixture(scope="session")
def evo(tmp_path_factory):
    """evo's ``core`` and ``file_interface`` modules; HOME points to a tmp folder so nothing is written
    outside it (evo keeps its settings in ``~/.evo``). Skips when evo is not installed."""
    # HOME only while evo is imported (it reads its settings then): a HOME changed for the rest of the
    # session broke later tests that read ~ (a local Ray's ~/.ray/auth_token)
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("HOME", str(tmp_path_factory.mktemp("evo_home")))
        pytest.importorskip("evo")
        mods = {
            name: importlib.import_module(f"evo.{name}")
            for name in ("core.sync", "core.metrics", "core.trajectory", "core.filters", "tools.file_interface")
        }
    return type("Evo", (), {k.split(".")[-1]: v for k, v in mods.items()})
