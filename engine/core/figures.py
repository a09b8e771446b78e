"""Saving a matplotlib figure as an output (``save_figure``): atomically (``<name>.part``, then
renamed, see ``engine/core/outputs.py``), in the format its name asks for, without matplotlib's
warnings on the user's terminal. Every plot the project writes goes through it."""

from __future__ import annotations

import warnings
from pathlib import Path

from .outputs import atomic_output


def save_figure(fig, path, *, dpi: int = 110) -> Path:
    """Write ``fig`` to ``path`` (the format from its suffix, PNG without one) and return the
    path; an unwritable destination is an ``OutputError`` naming it."""
    path = Path(path)
    fmt = path.suffix.lstrip(".").lower() or "png"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with atomic_output(path, what="plot") as f:
            fig.savefig(f, format=fmt, dpi=dpi)
    return path
