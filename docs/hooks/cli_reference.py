"""MkDocs hook: the CLI reference page (``cli.md``), generated at build time from the argparse
parser of the ``stillpoint`` command (``stillpoint.tools.cli.build_parser``), so every command,
subcommand and option the parser knows is on the page and nothing is copied by hand."""

from __future__ import annotations

import argparse
import os

PAGE = "cli.md"
WIDTH = "100"  # the help text's line width (argparse reads $COLUMNS)


def _subcommands(parser: argparse.ArgumentParser):
    """(name, one-line help, parser) of each subcommand of ``parser``, in the parser's order."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            helps = {a.dest: a.help for a in action._choices_actions}
            for name, sub in action.choices.items():
                yield name, helps.get(name) or "", sub


def _cell(text: str) -> str:
    return " ".join(text.split()).replace("|", "\\|")


def _anchor(prog: str) -> str:
    return "-".join(prog.split()[1:]) or "stillpoint"


def _section(prog: str, summary: str, parser: argparse.ArgumentParser, level: int) -> list:
    lines = [f"{'#' * level} `{prog}` {{#{_anchor(prog)}}}", ""]
    if summary:
        lines += [summary, ""]
    lines += ["```text", parser.format_help().rstrip(), "```", ""]
    for name, help_, sub in _subcommands(parser):
        lines += _section(f"{prog} {name}", help_, sub, min(level + 1, 4))
    return lines


def render() -> str:
    """The whole page as Markdown."""
    from stillpoint.tools.cli import build_parser

    old = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = WIDTH
    try:
        parser = build_parser()
        commands = list(_subcommands(parser))
        lines = ["# Command-line reference", "",
                 "Generated from the `stillpoint` command's own parser when the site is built: "
                 "the text under each command is its `--help`. Every command reports bad input "
                 "as one line naming the file and what was wrong, with exit code 2.", "",
                 "| command | what it does |", "|---|---|"]
        lines += [f"| [`{name}`](#{name}) | {_cell(help_)} |" for name, help_, _ in commands]
        lines += ["", "## `stillpoint` {#stillpoint}", "", "```text",
                  parser.format_help().rstrip(), "```", ""]
        for name, help_, sub in commands:
            lines += _section(f"stillpoint {name}", help_, sub, 2)
        return "\n".join(lines) + "\n"
    finally:
        if old is None:
            os.environ.pop("COLUMNS", None)
        else:
            os.environ["COLUMNS"] = old


def on_files(files, config):
    from mkdocs.structure.files import File

    files.append(File.generated(config, PAGE, content=render()))
    return files
