"""engine/run/summary.py: the run summary is one typed record whose fields are its docs."""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

from stillpoint.engine.run import RunSettings, process_file
from stillpoint.engine.run.summary import RunSummary, docs_table

# the repository's root: the folder above this test that holds pyproject.toml
ROOT = next(p for p in Path(__file__).resolve().parents if (p / "pyproject.toml").is_file())
sys.path.insert(0, str(ROOT / "tools"))

import summary_docs  # noqa: E402  (tools/summary_docs.py: the page's table between its markers)


def test_the_docs_table_is_generated_from_the_fields():
    """docs/columns.md's run-summary table is RunSummary's field list: a field added without a
    unit and meaning, or without regenerating the page, fails here."""
    for f in dataclasses.fields(RunSummary):
        assert f.metadata.get("unit") and f.metadata.get("meaning"), f.name
    _before, table, _after = summary_docs.split_page(summary_docs.PAGE.read_text())
    assert table == "\n" + docs_table(), (
        "docs/columns.md's run-summary table differs from RunSummary's fields: run "
        "`python tools/summary_docs.py`")


def test_the_docs_table_check_finds_a_field_without_docs(monkeypatch):
    @dataclasses.dataclass
    class Grown(RunSummary):
        extra_count: int = 0

    import stillpoint.engine.run.summary as summary_mod
    monkeypatch.setattr(summary_mod, "RunSummary", Grown)
    assert "extra_count" not in summary_docs.PAGE.read_text()
    try:
        docs_table()
    except KeyError:  # no unit / meaning for the new field
        return
    raise AssertionError("a field without docs went into the table")


def test_as_dict_keeps_field_order_and_leaves_out_optional_fields_that_are_none():
    s = RunSummary(input="x.cwa", mode="batch", device={}, samples=3, enmo_mean_mg=None,
                   wall_s=1.5, timezone="unknown")
    d = s.as_dict()
    assert list(d) == [f.name for f in dataclasses.fields(RunSummary)
                       if not (f.metadata["optional"] and getattr(s, f.name) is None)]
    assert d["enmo_mean_mg"] is None and "start_ns" not in d and "tables" not in d
    assert "wall_s" not in s.as_dict(log=True)


def test_a_run_returns_every_field_it_fills(tmp_path, real_file):
    """Keys of a real run's summary are RunSummary's fields, in field order."""
    summary = process_file(real_file("ax3_ggirread_testfile_100hz_145blocks.cwa"),
                           tmp_path / "run.mcap", RunSettings(mode="online"))
    names = [f.name for f in dataclasses.fields(RunSummary)]
    assert list(summary) == [n for n in names if n in summary]
    assert {"estimates", "start_ns", "mcap_messages"} <= set(summary)
