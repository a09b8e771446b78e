"""The `stillpoint` command line: one subcommand per user task, each a thin layer over the API.

Subcommands live in ``tools/cli/commands/<name>.py``; each module defines

    NAME = "inspect"                      # the subcommand
    HELP = "one line for --help"
    def add_arguments(parser): ...        # argparse arguments
    def run(args) -> int: ...             # exit code

and is found automatically. A module with ``KEEPS_EXISTING_OUTPUTS = True`` gets ``--overwrite``:
without it, an output that already exists is refused before any work. Any ``StillpointError`` (bad input) becomes exit code 2 with one line
on stderr, and so does a bad argument (``CommandLineParser``; numbers are checked by the types in
``commands/_numbers.py``); a ``KeyboardInterrupt`` exits 130.
"""

from __future__ import annotations

import argparse
import importlib
import os
import pkgutil
import sys

from stillpoint.engine.core.errors import StillpointError

from . import commands as _commands


def _command_modules(only=None):
    for info in sorted(pkgutil.iter_modules(_commands.__path__), key=lambda i: i.name):
        if info.name.startswith("_") or (only is not None and info.name != only):
            continue
        mod = importlib.import_module(f"{_commands.__name__}.{info.name}")
        if hasattr(mod, "NAME") and hasattr(mod, "run"):
            yield mod


def _only_requested(argv) -> "str | None":
    """Module name of the requested subcommand when it can be loaded alone (fast start-up:
    ``stillpoint inspect`` need not import the engine and scipy for the other commands)."""
    if not argv or argv[0].startswith("-"):
        return None
    name = argv[0].replace("-", "_")
    for info in pkgutil.iter_modules(_commands.__path__):
        if info.name == name and not name.startswith("_"):
            mod = importlib.import_module(f"{_commands.__name__}.{name}")
            return name if getattr(mod, "NAME", None) == argv[0] and hasattr(mod, "run") else None
    return None


class CommandLineParser(argparse.ArgumentParser):
    """argparse with one-line errors: ``stillpoint CMD: error: argument --rate: ...`` and exit
    code 2, without the usage block (``stillpoint CMD --help`` still shows it). Subcommand
    parsers are of the same class (argparse makes them with the parent's class)."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {' '.join(message.split())}\n")


class _VersionAction(argparse.Action):
    """``--version``: the installed distribution's version, looked up only when asked for (the
    lookup imports importlib.metadata and email, ~40 ms of every command's start-up)."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS,
                 help="show program's version number and exit"):
        super().__init__(option_strings, dest=dest, default=default, nargs=0, help=help)

    def __call__(self, parser, namespace, values, option_string=None):
        import stillpoint
        parser._print_message(f"stillpoint {getattr(stillpoint, '__version__', '0+unknown')}\n",
                              sys.stdout)
        parser.exit()


def build_parser(only=None) -> argparse.ArgumentParser:
    parser = CommandLineParser(
        prog="stillpoint",
        description="Streaming engine for raw wearable-accelerometer data (AX3/AX6 .cwa, GENEActiv .bin).")
    parser.add_argument("--version", action=_VersionAction)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for mod in _command_modules(only):
        p = sub.add_parser(mod.NAME, help=getattr(mod, "HELP", None),
                           description=getattr(mod, "DESCRIPTION", getattr(mod, "HELP", None)))
        if hasattr(mod, "add_arguments"):
            mod.add_arguments(p)
        if getattr(mod, "KEEPS_EXISTING_OUTPUTS", False):
            p.add_argument("--overwrite", action="store_true",
                           help="replace outputs that already exist (without it an existing "
                                "output is refused before any work)")
            p.set_defaults(_keeps_outputs=True)
        p.set_defaults(_run=mod.run)
    return parser


def _partial_note(e: BaseException) -> str:
    """Where an interrupted or failed run left its partial MCAP, and how to salvage it."""
    part = getattr(e, "partial_output", None)
    if not part or "stillpoint recover" in str(e):
        return ""
    return f"; the partial log {part} is kept: `stillpoint recover {part}` salvages it"


def _interrupt_note(args) -> str:
    """When the interruption carries no partial log: the one on disk, or that none exists
    (batch pass 1 writes nothing)."""
    if args.command not in ("process", "replay", "align"):
        return ""
    try:
        from pathlib import Path

        from stillpoint.engine.recover import is_finished
        out = getattr(args, "output", None)
        if out is None and args.command in ("process", "replay"):
            from .commands.process import default_output
            out = default_output(Path(args.file))
        if out is None:
            return ""
        out = Path(out)
        for cand in (out.with_name(out.name + ".part"), out):
            if cand.is_file() and cand.stat().st_size and not is_finished(cand):
                return (f"; the partial log {cand} keeps every chunk written so far: "
                        f"`stillpoint recover {cand} -o FIXED.mcap` salvages it")
        return (f"; no partial log was left (batch mode writes {out} only in its second pass; "
                "an existing complete output is untouched)")
    except Exception:  # the note is a courtesy: never mask the interruption
        return ""


def _note_sigint(seen: list):
    """While the command loads: SIGINT raises KeyboardInterrupt as Python's own handler does and
    is also appended to ``seen``. Returns the function that puts the previous handler back (a
    SIGINT the caller ignores, or a call off the main thread, is left alone)."""
    import signal

    def note(signum, frame):
        seen.append(signum)
        raise KeyboardInterrupt

    try:
        if signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
            return lambda: None
        signal.signal(signal.SIGINT, note)
    except ValueError:  # not the main thread
        return lambda: None
    return lambda: signal.signal(signal.SIGINT, signal.default_int_handler)


# the arguments that name files a command reads (recordings, logs, tables, profiles, models)
INPUT_ARGUMENTS = ("file", "files", "reference", "other", "input", "right_file", "inputs",
                   "prior", "profile", "static", "model", "truth")


def _input_files(args) -> list:
    out = []
    for name in INPUT_ARGUMENTS:
        v = getattr(args, name, None)
        if isinstance(v, (list, tuple)):
            out += [x for x in v if isinstance(x, (str, os.PathLike))]
        elif isinstance(v, (str, os.PathLike)):
            out.append(v)
    return out


def main(argv=None) -> int:
    import warnings
    # the plots' library warnings (fonts, layout) are not the user's business: stderr carries
    # only stillpoint's own one-line messages
    warnings.filterwarnings("ignore", module=r"matplotlib(\..*)?$")
    argv = sys.argv[1:] if argv is None else list(argv)
    # building the parser imports the command's modules: a Ctrl-C there is one line too. An
    # extension module's initialisation can turn the KeyboardInterrupt into an ImportError
    # (numpy's does, while it imports datetime), so the SIGINT is also noted as it arrives.
    sigints = []
    restore = _note_sigint(sigints)
    try:
        parser = build_parser(_only_requested(argv))
        args = parser.parse_args(argv)
    except SystemExit as e:  # --help, --version, or a bad argument (one line already printed)
        return e.code if isinstance(e.code, int) else (0 if e.code is None else 2)
    except (KeyboardInterrupt, ImportError) as e:
        if isinstance(e, ImportError) and not sigints:
            raise
        print("stillpoint: interrupted", file=sys.stderr)
        return 130
    finally:
        restore()
    if not getattr(args, "_run", None):
        parser.print_help()
        return 2
    from stillpoint.engine.core.outputs import keep_existing_outputs, protect_inputs
    protect_inputs(_input_files(args))
    keep_existing_outputs(getattr(args, "_keeps_outputs", False)
                          and not getattr(args, "overwrite", False))
    try:
        return int(args._run(args) or 0)
    except StillpointError as e:
        print(f"stillpoint {args.command}: error: {e}{_partial_note(e)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as e:
        print(f"stillpoint {args.command}: interrupted{_partial_note(e) or _interrupt_note(args)}",
              file=sys.stderr)
        return 130
    except BrokenPipeError:
        return 0
    except OSError as e:  # a file system failure no command anticipated: still one line
        from stillpoint.engine.core.outputs import describe_os_error
        where = f"{e.filename}: " if getattr(e, "filename", None) else ""
        print(f"stillpoint {args.command}: error: {where}{describe_os_error(e)}", file=sys.stderr)
        return 2
    finally:
        protect_inputs(())  # for this command only (main() is also called in-process)
        keep_existing_outputs(False)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
