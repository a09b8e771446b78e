"""engine/core/figures.py: save_figure is the one way a figure is saved."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from stillpoint.engine.core.figures import save_figure
from stillpoint.engine.core.outputs import OutputError

ROOT = Path(__file__).resolve().parents[3]


def test_no_module_saves_a_figure_but_save_figure():
    calls = [f"{p.relative_to(ROOT)}:{i}" for folder in ("engine", "drivers", "tools", "_stillpoint")
             for p in sorted((ROOT / folder).rglob("*.py"))
             for i, line in enumerate(p.read_text().splitlines(), 1)
             if re.search(r"\.savefig\(", line)]
    assert calls == ["engine/core/figures.py:23"], calls


def test_save_figure_writes_the_format_its_name_asks_for_atomically(tmp_path):
    mpl = pytest.importorskip("matplotlib")
    mpl.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(2, 2))
    ax.plot([0, 1], [0, 1])
    png = save_figure(fig, tmp_path / "a.png", dpi=50)
    svg = save_figure(fig, tmp_path / "a.svg")
    forced = save_figure(fig, tmp_path / "b.out", fmt="png")
    plt.close(fig)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert b"<svg" in svg.read_bytes()[:500]
    assert forced.read_bytes()[:4] == b"\x89PNG"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.png", "a.svg", "b.out"]  # no .part left
    with pytest.raises(OutputError, match="missing"):
        save_figure(fig, tmp_path / "missing" / "c.png")
