"""The ``vslam`` command. Thin: each sub-command module parses its arguments and calls the API.

Every sub-command lives in ``vslam/cli/<name>_cmd.py`` and exposes
``add_parser(subparsers) -> argparse.ArgumentParser`` (setting ``func=run``) and ``run(args) -> int``.
Errors derived from :class:`vslam.errors.VslamError` are printed as one line and exit with 2.
"""
from __future__ import annotations

import argparse
import importlib
import logging
import sys

from vslam import __version__
from vslam.errors import VslamError

# Sub-command modules, in the order `vslam --help` lists them. Missing ones are skipped so the
# command keeps working while stages are still being written.
COMMANDS = ["demo", "run", "eval", "localize", "calibrate", "reconstruct", "vocab", "bench", "report"]

log = logging.getLogger("vslam")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="vslam", description="Visual SLAM: monocular, stereo, RGB-D.")
    parser.add_argument("--version", action="version", version=f"vslam {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv for debug)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMANDS:
        try:
            module = importlib.import_module(f"vslam.cli.{name}_cmd")
        except ModuleNotFoundError as exc:
            if exc.name == f"vslam.cli.{name}_cmd":
                continue
            raise
        module.add_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    level = logging.WARNING - 10 * min(args.verbose, 2)
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
    if not getattr(args, "func", None):
        parser.print_help()
        return 1
    try:
        return int(args.func(args) or 0)
    except VslamError as exc:
        print(f"vslam {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"vslam {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
