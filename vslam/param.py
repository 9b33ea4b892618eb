"""``param(default, doc, bounds)``: a dataclass field that carries its one-line documentation and
its valid range.

Every configuration dataclass declares its fields with :func:`param` (a leaf setting) or
:func:`section` (a nested group of settings), so ``vslam config`` and ``docs/settings.md`` list
each key with its default, range and doc from this single source. A numeric setting's ``bounds``
(``"[1, 32]"``, ``"(0, 1]"``: brackets include the end, parentheses exclude it; ``inf`` allowed) are
checked by :func:`vslam.config.from_dict` once the configuration is built, so a value from ``--set``
or a ``--config`` file outside them is one :class:`~vslam.errors.ConfigError` naming the key and the
range. Lowest layer: imports nothing of vslam.
"""
from __future__ import annotations

import dataclasses
import math
import re
from typing import Any

_BOUNDS_RE = re.compile(r"^\s*([\[(])\s*([-+0-9.eEinf]+)\s*,\s*([-+0-9.eEinf]+)\s*([\])])\s*$")


@dataclasses.dataclass(frozen=True)
class Bounds:
    """A closed, open or half-open interval ``text`` (``"[1, 32]"``, ``"(0, 1]"``)."""

    lo: float
    hi: float
    lo_open: bool
    hi_open: bool
    text: str

    @classmethod
    def parse(cls, text: str) -> "Bounds":
        m = _BOUNDS_RE.match(text)
        if m is None:
            raise ValueError(f"bounds {text!r}: write an interval such as '[1, 32]' or '(0, 1]'")
        lo, hi = float(m.group(2)), float(m.group(3))
        if not lo <= hi:
            raise ValueError(f"bounds {text!r}: the lower end is above the upper end")
        return cls(lo, hi, m.group(1) == "(", m.group(4) == ")", f"{m.group(1)}{m.group(2)}, {m.group(3)}{m.group(4)}")

    def contains(self, value: Any) -> bool:
        """Whether the number ``value`` (or every number of a list/tuple ``value``) lies inside."""
        if isinstance(value, (list, tuple)):
            return all(self.contains(v) for v in value)
        if value is None or isinstance(value, bool) or not isinstance(value, (int, float)):
            return True  # None (an optional setting left unset) or not a number: the type check's job
        if isinstance(value, float) and math.isnan(value):
            return False
        above = value > self.lo if self.lo_open else value >= self.lo
        below = value < self.hi if self.hi_open else value <= self.hi
        return above and below


def param(default: Any, doc: str, bounds: str | None = None) -> Any:
    """A dataclass field with default ``default``, the one-line ``doc`` and, for a number, its valid
    range ``bounds`` (``"[1, 32]"``) in its metadata."""
    metadata: dict[str, Any] = {"doc": doc}
    if bounds is not None:
        metadata["bounds"] = Bounds.parse(bounds)
    return dataclasses.field(default=default, metadata=metadata)


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


def bounds_of(f: dataclasses.Field) -> Bounds | None:
    """The valid range declared with :func:`param` (None when it declares none)."""
    return f.metadata.get("bounds")
