"""The documentation agrees with the code: the README's test command is the one CI runs, its links
and the site's relative links point at files that exist, every page is in the site's navigation,
the generated CLI reference covers every command, and the output-column reference lists exactly
the columns (and summary keys) the code writes.

The site itself is built with ``mkdocs build --strict`` by ``.ci/run`` after the tests (the
``docs`` extra), so the test extra needs no documentation tooling; these checks need none either.
"""

from __future__ import annotations

import importlib
import importlib.util
import pkgutil
import re
from pathlib import Path


ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"
GENERATED_PAGES = {"cli.md"}  # written at build time by docs/hooks/cli_reference.py
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")


def _relative_targets(md: str):
    for target in LINK.findall(md):
        if re.match(r"[a-z]+:", target) or target.startswith("#"):
            continue
        yield target.split("#", 1)[0]


def _cli_hook():
    spec = importlib.util.spec_from_file_location("cli_reference", DOCS / "hooks" / "cli_reference.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_readme_test_command_is_the_one_ci_runs():
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8").splitlines()
    marker = next(i for i, line in enumerate(ci) if "the README's test command" in line)
    command = ci[marker + 1].strip()
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    setup = [line.strip() for line in readme.splitlines() if line.startswith("    python3 -m venv")]
    assert len(setup) == 2, setup
    assert setup[1].endswith(command), (setup[1], command)
    assert setup[0].endswith("pip install -e . && stillpoint demo")


def test_readme_is_short_and_its_links_exist():
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert len(readme.splitlines()) <= 200
    targets = list(_relative_targets(readme))
    assert any(t.startswith("docs/") for t in targets)
    missing = [t for t in targets if not (ROOT / t).exists()]
    assert not missing, f"README links to files that do not exist: {missing}"


def test_site_links_point_at_pages_of_the_site():
    missing = []
    for page in sorted(DOCS.glob("*.md")):
        for target in _relative_targets(page.read_text(encoding="utf-8")):
            if not target or target in GENERATED_PAGES:
                continue
            resolved = (page.parent / target).resolve()
            if not resolved.exists() or DOCS.resolve() not in resolved.parents:
                missing.append(f"{page.name} -> {target}")  # absent, or outside the site
    assert not missing, missing


def test_every_page_is_in_the_navigation():
    config = (ROOT / "mkdocs.yml").read_text(encoding="utf-8")
    nav = set(re.findall(r"^\s*-\s+[^:\n]+:\s+(\S+\.md)\s*$", config, flags=re.M))
    pages = {p.name for p in DOCS.glob("*.md")} | GENERATED_PAGES
    assert pages - nav == set(), f"pages missing from mkdocs.yml's nav: {sorted(pages - nav)}"
    assert nav - pages == set(), f"nav entries without a page: {sorted(nav - pages)}"


def test_cli_reference_has_every_command_and_subcommand():
    from stillpoint.tools import cli
    from stillpoint.tools.cli import build_parser

    commands = cli._commands  # the package the command line finds its subcommands in

    page = _cli_hook().render()
    names = []
    for info in pkgutil.iter_modules(commands.__path__):
        if info.name.startswith("_"):
            continue
        mod = importlib.import_module(f"{commands.__name__}.{info.name}")
        if hasattr(mod, "NAME") and hasattr(mod, "run"):
            names.append(mod.NAME)
    assert len(names) >= 20
    for name in names:
        assert f"## `stillpoint {name}` {{#{name}}}" in page, name
        assert f"usage: stillpoint {name}" in page, name
    # nested subcommands (device download, cohort run, calibration show, ...) get their own section
    import argparse
    for action in build_parser()._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                for inner in sub._actions:
                    if isinstance(inner, argparse._SubParsersAction):
                        for leaf in inner.choices:
                            assert f"`stillpoint {name} {leaf}` {{#{name}-{leaf}}}" in page
                            assert f"usage: stillpoint {name} {leaf}" in page


# --- the output-column reference (docs/columns.md) ---

def _documented(section_id: str) -> list:
    """Column names of the first table under the heading ``{#section_id}``, in order (a first
    cell may list several names in backticks)."""
    text = (DOCS / "columns.md").read_text(encoding="utf-8")
    start = text.index(f"{{#{section_id}}}")
    body = text[start:].split("\n## ", 1)[0]
    rows = [line for line in body.splitlines() if line.startswith("| `")]
    assert rows, section_id
    names = []
    for row in rows:
        first = re.split(r"(?<!\\)\|", row)[1]
        names += re.findall(r"`([^`]+)`", first)
    return names


def _bands():
    from stillpoint.engine.tables import day_columns
    return [c for c in day_columns() if c.startswith("min_enmo_")]


def _expand(fields):
    out = []
    for f in fields:
        out += _bands() if f == "BANDS" else [f]
    return out


def test_epoch_columns_are_documented():
    from stillpoint.engine.tables import EPOCH_COLUMNS
    assert _documented("epoch-table") == list(EPOCH_COLUMNS)


def test_count_columns_are_documented():
    from stillpoint.engine.tables.writer import metric_columns
    assert _documented("epoch-metric-columns") == metric_columns(True, True)


def test_day_columns_are_documented():
    from stillpoint.engine.tables import day_columns
    assert _documented("day-table") == day_columns()


def test_night_columns_are_documented():
    from stillpoint.engine.sleep import table
    text = (DOCS / "columns.md").read_text(encoding="utf-8")
    section = text[text.index("{#nights-table}"):].split("\n## ", 1)[0]
    tables = section.split("| column | unit | meaning |")[1:]
    names = [re.findall(r"^\| `([^`]+)`", t, flags=re.M) for t in tables]
    assert names[0] == table.NIGHT_COLUMNS
    assert names[1] == table.DAY_NIGHT_COLUMNS


def test_rhythm_columns_are_documented():
    from stillpoint.engine.rhythm import RHYTHM_COLUMNS
    assert _documented("rhythm-table") == RHYTHM_COLUMNS


def test_windows_columns_are_documented():
    from stillpoint.engine.timeuse import WINDOW_COLUMNS
    assert _documented("windows-table") == WINDOW_COLUMNS


def test_cohort_table_columns_are_documented():
    c = importlib.import_module("stillpoint.engine.cohort.collate")
    assert _documented("cohort-summary") == _expand(c.SUMMARY_FIELDS)
    assert _documented("cohort-participants") == _expand(c.PARTICIPANT_FIELDS)
    assert _documented("cohort-failures") == list(c.FAILURE_FIELDS)


def test_cohort_days_columns_are_documented(tmp_path):
    """A real collation of one processed file: the stacked day table's leading columns are the
    documented ones, followed by the day table's."""
    from stillpoint.engine.cohort import collate, discover_inputs, make_plan, run_cohort
    from stillpoint.engine.run import RunSettings
    from stillpoint.engine.sim import simulate_recording
    from stillpoint.engine.tables import day_columns

    rec = tmp_path / "in" / "p01.cwa"
    rec.parent.mkdir()
    simulate_recording(rec, days=0.05, hz=12.5, seed=4, truth_path=False)
    out = tmp_path / "out"
    plan = make_plan(discover_inputs([str(rec.parent)]), RunSettings(timezone="UTC"))
    plan.write(out)
    run_cohort(plan, out, scheduler="serial", progress=False)
    res = collate(out)
    header = (out / "cohort_days.csv").read_text(encoding="utf-8").splitlines()[0].split(",")
    lead = _documented("cohort-days")
    from stillpoint.engine.sleep.table import DAY_NIGHT_COLUMNS  # sleep is on by default
    assert header == lead + [c for c in day_columns() if c != "date"] + DAY_NIGHT_COLUMNS, res.failures
    summary = (out / "cohort_summary.csv").read_text(encoding="utf-8").splitlines()[0].split(",")
    assert summary == _documented("cohort-summary")


def test_run_summary_keys_are_documented(tmp_path):
    from stillpoint.engine.run import RunSettings, process_file
    from stillpoint.engine.sim import simulate_recording
    from stillpoint.engine.tables import TablesSettings, table_paths

    rec = tmp_path / "r.cwa"
    simulate_recording(rec, days=0.05, hz=12.5, seed=4, truth_path=False)
    out = tmp_path / "r.mcap"
    summary = process_file(rec, out, RunSettings(timezone="UTC"), tables=TablesSettings(*table_paths(out)))
    text = (DOCS / "columns.md").read_text(encoding="utf-8")
    section = text[text.index("{#run-summary}"):].split("\n## ", 1)[0]
    documented = set(re.findall(r"`([a-z_]+)`", section))
    assert set(summary) - documented == set(), sorted(set(summary) - documented)
    for nested in ("calibration", "qc", "tables", "outputs", "device", "clipping"):
        assert set(summary[nested]) - documented == set(), (nested, sorted(set(summary[nested]) - documented))
