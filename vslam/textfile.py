"""Reading small text inputs (lists, calibrations, trajectories) with one-line errors.

:func:`open_text` decodes the whole file first, so a byte that is not UTF-8 is reported as
``FILE:LINE`` by the caller's error class instead of a ``UnicodeDecodeError`` traceback mid-parse.
:func:`load_yaml_text` parses YAML with aliases (memory bombs) refused.
"""
from __future__ import annotations

import functools
import io
import re
from pathlib import Path

from vslam.errors import VslamError


def open_text(path: str | Path, error: type[VslamError] = VslamError, max_bytes: int | None = None) -> io.StringIO:
    """The text of ``path`` (UTF-8, optional BOM) as a file object; unreadable or non-UTF-8
    content raises ``error`` naming the file and line. ``max_bytes``: a larger file is refused
    before it is read (a settings file or spec is kilobytes, not 100 MB)."""
    path = Path(path)
    try:
        if max_bytes is not None and path.stat().st_size > max_bytes:
            raise error(f"{path}: {path.stat().st_size} bytes is too large for this kind of file (at most "
                        f"{max_bytes} bytes are read); pass the right file")
        data = path.read_bytes()
    except OSError as exc:
        raise error(f"{path}: cannot read ({exc.strerror or exc})") from None
    try:
        return io.StringIO(data.decode("utf-8-sig"))
    except UnicodeDecodeError as exc:
        line = data[:exc.start].count(b"\n") + 1
        raise error(f"{path}:{line}: byte 0x{data[exc.start]:02x} is not UTF-8 text; the file must be plain "
                    "text, fix or re-create that line") from None


@functools.lru_cache(maxsize=1)
def _yaml_loader():
    """A safe loader (libyaml's ``CSafeLoader`` where PyYAML has it: 10x faster than the Python
    one on a run's ``config.yaml``, which every ``vslam map`` task reads) that reads ``1e-5`` /
    ``2E+3`` (a number in YAML 1.2 and JSON; YAML 1.1 makes it text) as a float."""
    import yaml

    class NumberLoader(getattr(yaml, "CSafeLoader", yaml.SafeLoader)):  # type: ignore[misc, valid-type]
        pass

    NumberLoader.add_implicit_resolver(
        "tag:yaml.org,2002:float", re.compile(r"^[-+]?[0-9][0-9_]*(?:\.[0-9_]*)?[eE][-+]?[0-9]+$"),
        list("-+0123456789"))
    return NumberLoader


def _refuse_aliases(text: str) -> None:
    """Raise :class:`_AliasRefused` at the first alias (``*name``) of ``text``: its events are read
    before any node is built, so an alias bomb costs nothing."""
    import yaml

    if "*" not in text:  # no alias without its indicator
        return
    for event in yaml.parse(text, Loader=_yaml_loader()):
        if isinstance(event, yaml.AliasEvent):
            raise _AliasRefused(event.anchor, event.start_mark.line + 1)


class _AliasRefused(Exception):
    def __init__(self, anchor: str, line: int) -> None:
        super().__init__(anchor, line)
        self.anchor, self.line = anchor, line


def load_yaml_text(text: str, path: str | Path, error: type[VslamError] = VslamError):
    """Parse small YAML input (``yaml.safe_load``, plus ``1e-5`` read as a number) with aliases
    refused: ``*name`` repeats a node without copying text, so a few KB of nested aliases expand to
    gigabytes (a memory bomb); no calibration, setting or spec needs one. Errors raise ``error``
    naming the file and line."""
    import yaml

    try:
        _refuse_aliases(text)
        return yaml.load(text, Loader=_yaml_loader())  # noqa: S506 - a SafeLoader subclass
    except _AliasRefused as exc:
        raise error(f"{path}:{exc.line}: YAML alias '*{exc.anchor}' refused (aliases can expand to gigabytes); "
                    "write the values out") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"{path}:{mark.line + 1}" if mark is not None else f"{path}"
        raise error(f"{where}: not valid YAML ({getattr(exc, 'problem', None) or type(exc).__name__}); fix its "
                    "syntax") from None
