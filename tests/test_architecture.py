"""The layer table of docs/architecture.md holds: the import-linter contracts in pyproject.toml
(layers low to high, stages independent) are kept, lazy (function-level) imports included."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_import_contracts_are_kept():
    pytest.importorskip("importlinter")
    code = "import sys; from importlinter.cli import lint_imports_command; sys.exit(lint_imports_command())"
    proc = subprocess.run([sys.executable, "-c", code, "--no-cache"], cwd=ROOT, capture_output=True, text=True,
                          env={**os.environ, "PYTHONPATH": str(ROOT)}, timeout=300)
    assert proc.returncode == 0, proc.stdout[-4000:] + proc.stderr[-2000:]
    assert "2 kept, 0 broken" in proc.stdout


def test_contracts_name_every_subpackage():
    """A new top-level module or package must be placed in the layer table (else it is unchecked)."""
    import tomllib

    cfg = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]["contracts"]
    layers = next(c for c in cfg if c["id"] == "layers")["layers"]
    listed = {m.strip().removeprefix("vslam.") for layer in layers for m in layer.replace(":", "|").split("|")}
    present = {p.stem for p in (ROOT / "vslam").iterdir()
               if (p.suffix == ".py" and p.stem not in ("__init__", "__main__")) or (p / "__init__.py").exists()}
    assert present == listed, f"not in the layer table: {sorted(present - listed)}; gone: {sorted(listed - present)}"
