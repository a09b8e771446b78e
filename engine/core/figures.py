"""Saving a matplotlib figure as an output (``save_figure``): atomically (``<name>.part``, then
renamed, see ``engine/core/outputs.py``), in the format its name asks for, without matplotlib's
warnings on the user's terminal. Every plot the project writes goes through it."""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Optional, Union

from .outputs import atomic_output


def save_figure(fig, path, *, dpi: Union[float, str] = 110, fmt: Optional[str] = None) -> Path:
    """Write ``fig`` to ``path`` and return the path: ``fmt`` (default: from the name's suffix,
    PNG without one) at ``dpi`` (``"figure"``: the figure's own). An unwritable destination is
    an ``OutputError`` naming it."""
    path = Path(path)
    fmt = fmt or path.suffix.lstrip(".").lower() or "png"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with atomic_output(path, what="plot") as f:
            fig.savefig(f, format=fmt, dpi=dpi)
    return path
