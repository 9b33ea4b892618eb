"""``param(default, doc)``: a dataclass field that carries its one-line documentation.

Every configuration dataclass declares its fields with :func:`param` (a leaf setting) or
:func:`section` (a nested group of settings), so ``vslam config`` and ``docs/settings.md`` list
each key with its default and doc from this single source. Lowest layer: imports nothing of vslam.
"""
from __future__ import annotations

import dataclasses
from typing import Any


def param(default: Any, doc: str) -> Any:
    """A dataclass field with default ``default`` and the one-line ``doc`` in its metadata."""
    return dataclasses.field(default=default, metadata={"doc": doc})


def section(cls: type, doc: str, flat_prefixes: tuple[str, ...] = (), flat_keys: dict[str, str] | None = None) -> Any:
    """A nested group of settings (a frozen dataclass ``cls``, defaults from ``cls()``).

    ``flat_prefixes``: the group's settings were once flat fields of the parent named
    ``prefix + name``; ``flat_keys``: old flat names that follow no prefix (``{"fuse": "enabled"}``).
    :func:`vslam.config.from_dict` maps those old keys here (with a warning).
    """
    return dataclasses.field(default_factory=cls, metadata={"doc": doc, "flat_prefixes": flat_prefixes,
                                                            "flat_keys": dict(flat_keys or {})})


def doc_of(f: dataclasses.Field) -> str:
    """The one-line doc of a field declared with :func:`param` / :func:`section` ('' otherwise)."""
    return str(f.metadata.get("doc", ""))
