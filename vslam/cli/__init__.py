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
from vslam.signals import exit_status, interrupt_reason, terminate_as_interrupt

# Sub-command modules, in the order `vslam --help` lists them. Missing ones are skipped so the
# command keeps working while stages are still being written.
COMMANDS = ["demo", "run", "eval", "gt", "localize", "merge", "map", "calibrate", "reconstruct", "vocab", "bench", "report", "config"]

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
    terminate_as_interrupt()  # SIGTERM/SIGHUP stop a run like Ctrl-C: stats.json written, children stopped
    try:
        rc = int(args.func(args) or 0)
        sys.stdout.flush()  # a full or broken standard output fails here, inside this handler
        return rc
    except VslamError as exc:
        print(f"vslam {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:
        print(f"vslam {args.command}: {interrupt_reason(exc)}", file=sys.stderr)
        return exit_status(exc)
    except BrokenPipeError:  # e.g. `vslam ... | head`: nothing more to say
        return 1
    except OSError as exc:  # full disk, permissions: the environment, not the input
        from vslam.outputs import os_error_hint

        if exc.filename:
            msg = f"{exc.filename}: {exc.strerror or exc}; {os_error_hint(exc, 'check the path and its permissions and rerun')}"
        else:  # no file named: our own writes name theirs, so it is the standard output
            msg = (f"cannot write to the standard output ({exc.strerror or exc}): the file or device it is "
                   "redirected to refused it; redirect it elsewhere")
        print(f"vslam {args.command}: error: {msg}", file=sys.stderr)
        log.debug("details", exc_info=True)
        return 1
    except MemoryError:
        print(f"vslam {args.command}: error: out of memory; use a smaller input or --max-frames", file=sys.stderr)
        return 1
    except Exception as exc:  # a bug: one line, the traceback with -vv
        print(f"vslam {args.command}: internal error: {type(exc).__name__}: {exc} (rerun with -vv for the "
              "traceback and report it)", file=sys.stderr)
        log.debug("traceback", exc_info=True)
        return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
