"""Reading small text inputs (lists, calibrations, trajectories) with one-line errors.

:func:`open_text` decodes the whole file first, so a byte that is not UTF-8 is reported as
``FILE:LINE`` by the caller's error class instead of a ``UnicodeDecodeError`` traceback mid-parse.
"""
from __future__ import annotations

import io
from pathlib import Path

from vslam.errors import VslamError


def open_text(path: str | Path, error: type[VslamError] = VslamError) -> io.StringIO:
    """The text of ``path`` (UTF-8, optional BOM) as a file object; unreadable or non-UTF-8
    content raises ``error`` naming the file and line."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise error(f"{path}: cannot read ({exc.strerror or exc})") from None
    try:
        return io.StringIO(data.decode("utf-8-sig"))
    except UnicodeDecodeError as exc:
        line = data[:exc.start].count(b"\n") + 1
        raise error(f"{path}:{line}: byte 0x{data[exc.start]:02x} is not UTF-8 text; the file must be plain "
                    "text, fix or re-create that line") from None
