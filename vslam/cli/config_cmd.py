"""``vslam config``: every setting (dotted key) with its default and one-line doc."""
from __future__ import annotations

import argparse
import sys


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "config", help="list every setting with its default and doc",
        description="Print every configuration key (as used by --set and YAML files) with its default value "
                    "and a one-line description. --markdown writes docs/settings.md.",
    )
    p.add_argument("prefix", nargs="?", default="", help="only the keys under this section, e.g. frontend.keyframes")
    p.add_argument("--markdown", action="store_true", help="emit the Markdown reference (docs/settings.md)")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    from vslam.config import Config, settings_markdown, settings_text
    from vslam.errors import ConfigError

    if args.markdown:
        sys.stdout.write(settings_markdown(Config))
        return 0
    text = settings_text(Config, args.prefix.rstrip("."))
    if not text:
        raise ConfigError(f"no setting {args.prefix!r}; `vslam config` lists them all")
    sys.stdout.write(text)
    return 0
