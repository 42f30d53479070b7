"""The ``plsgraph`` command. Library code raises typed errors; only this module prints."""

from __future__ import annotations

import argparse
import logging
import sys

from . import __version__
from .errors import PlsgraphError


def _build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="plsgraph",
        description="Calibrate an event camera against wheel odometry on a ground robot.",
    )
    p.add_argument("--version", action="version", version=f"plsgraph {__version__}")
    p.add_argument("-v", "--verbose", action="store_true", help="log progress details")
    sub = p.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    return p


def main(argv: list[str] | None = None) -> int:
    parser = _build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING, format="%(message)s")
    try:
        return int(args.func(args) or 0)
    except PlsgraphError as exc:
        print(f"plsgraph: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("plsgraph: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
