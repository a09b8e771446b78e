"""Rewrite the run-summary table on the Columns page (docs/columns.md) from the fields of
``stillpoint.engine.run.summary.RunSummary``.

    python tools/summary_docs.py [--check]

The table sits between the ``<!-- run-summary: start -->`` and ``<!-- run-summary: end -->``
markers; tests/engine/run/test_run_summary.py fails while it differs from the fields. ``--check`` compares
without writing (exit 1 when it differs).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from stillpoint.engine.run.summary import docs_table

PAGE = Path(__file__).resolve().parents[1] / "docs" / "columns.md"
START, END = "<!-- run-summary: start -->", "<!-- run-summary: end -->"


def split_page(text: str) -> tuple[str, str, str]:
    """(before the table, the table, after it) of the Columns page's text."""
    a = text.index(START) + len(START)
    b = text.index(END)
    return text[:a], text[a:b], text[b:]


def main(argv=None) -> int:
    """Compare, or rewrite, the page's table."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="compare only; write nothing")
    args = ap.parse_args(argv)
    before, table, after = split_page(PAGE.read_text())
    wanted = "\n" + docs_table()
    if table == wanted:
        print(f"{PAGE}: the run-summary table matches RunSummary")
        return 0
    if args.check:
        print(f"{PAGE}: the run-summary table differs from RunSummary's fields")
        return 1
    PAGE.write_text(before + wanted + after)
    print(f"{PAGE}: the run-summary table rewritten from RunSummary's fields")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
