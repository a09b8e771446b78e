"""The `stillpoint` command line: one subcommand per user task, each a thin layer over the API.

Subcommands live in ``tools/commands/<name>.py``; each module defines

    NAME = "inspect"                      # the subcommand
    HELP = "one line for --help"
    def add_arguments(parser): ...        # argparse arguments
    def run(args) -> int: ...             # exit code

and is found automatically. Any ``StillpointError`` (bad input) becomes exit code 2 with one line
on stderr; a ``KeyboardInterrupt`` exits 130.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys

from stillpoint.drivers.errors import StillpointError

from . import commands as _commands


def _command_modules():
    for info in sorted(pkgutil.iter_modules(_commands.__path__), key=lambda i: i.name):
        if info.name.startswith("_"):
            continue
        mod = importlib.import_module(f"{_commands.__name__}.{info.name}")
        if hasattr(mod, "NAME") and hasattr(mod, "run"):
            yield mod


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="stillpoint",
        description="Streaming engine for raw wearable-accelerometer data (AX3/AX6 .cwa, GENEActiv .bin).")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for mod in _command_modules():
        p = sub.add_parser(mod.NAME, help=getattr(mod, "HELP", None),
                           description=getattr(mod, "DESCRIPTION", getattr(mod, "HELP", None)))
        if hasattr(mod, "add_arguments"):
            mod.add_arguments(p)
        p.set_defaults(_run=mod.run)
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "_run", None):
        parser.print_help()
        return 2
    try:
        return int(args._run(args) or 0)
    except StillpointError as e:
        print(f"stillpoint {args.command}: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("stillpoint: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
