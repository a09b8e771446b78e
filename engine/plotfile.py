"""Saving a matplotlib figure as an output: atomically (``<name>.part``, then renamed, see
``stillpoint.drivers.outputs``), in the format its name asks for, without matplotlib's warnings
on the user's terminal."""

from __future__ import annotations

import warnings
from pathlib import Path

from stillpoint.drivers.outputs import atomic_output


def save_figure(fig, path, *, dpi: int = 110) -> Path:
    path = Path(path)
    fmt = path.suffix.lstrip(".").lower() or "png"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with atomic_output(path, what="plot") as f:
            fig.savefig(f, format=fmt, dpi=dpi)
    return path
