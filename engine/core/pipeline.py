"""Pipeline: a Source's Blocks, cut to a bounded size, through stages into sinks, with progress.

``Pipeline(source, stages, max_block_s=10).run(progress=cb)`` iterates the source once. Every
Block is first cut (at sector/page boundaries where possible) into pieces of at most
``max_block_s`` of data, so no stage ever holds more than that plus its ring buffers, whatever
the driver hands over; since every operator's output is independent of block cuts, the cut
changes nothing else. Each piece is passed to every stage in order (``stage.push(block)``),
then ``stage.flush()`` is called on each stage at the end. ``progress(stats)`` is called after
every piece with a ``PipelineStats`` (samples, data time, fraction done when the source knows).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Callable, Iterable, Optional, Protocol, runtime_checkable

import numpy as np

from .blocks import Block


@runtime_checkable
class Operator(Protocol):
    """An incremental, stateful stage of the pipeline (every class in engine/operators/ is one).

    ``push(item) -> outputs`` consumes one input item (a Block, a corrected batch, a feature
    table) and returns whatever became final because of it; ``flush() -> outputs`` returns what
    is still pending at the end of the stream. The invariant every operator keeps (and is
    property-tested for): the concatenated outputs do not depend on how the input stream was cut
    into items."""

    def push(self, item: Any) -> Any:
        """Consume one item; return the outputs it made final."""

    def flush(self) -> Any:
        """Return what is still pending at the end of the stream."""


@dataclass
class PipelineStats:
    """What a pipeline run saw: samples, blocks, first/last sample time, segments, wall time."""
    samples: int = 0
    blocks: int = 0
    first_ns: Optional[int] = None
    last_ns: Optional[int] = None
    segments: set = field(default_factory=set)
    wall_s: float = 0.0
    fraction: Optional[float] = None  # of the input consumed, when the source can tell

    @property
    def data_s(self) -> float:
        """Data time from the first to the last sample, in seconds."""
        if self.first_ns is None or self.last_ns is None:
            return 0.0
        return (self.last_ns - self.first_ns) / 1e9


def split_block(block: Block, max_samples: Optional[int]) -> list[Block]:
    """Cut a Block into pieces of at most ``max_samples`` (None: never), at unit boundaries
    where possible."""
    n = block.n
    if max_samples is None or n <= max_samples:
        return [block]
    us = block.unit_start
    out = []
    s = 0
    while s < n:
        limit = s + max_samples
        if limit >= n:
            e = n
        else:
            # the last unit boundary in (s, limit]; if none (a unit larger than the limit), cut inside
            k = int(np.searchsorted(us, limit, side="right")) - 1
            e = int(us[k]) if k >= 0 and us[k] > s else limit
        out.append(block.slice(s, e))
        s = e
    return out


class Pipeline:
    """A source pushed through a chain of stages, block by block (see the module docstring)."""
    def __init__(self, source, stages: Iterable[Operator], *, rate_hz: float,
                 max_block_s: Optional[float] = 10.0):
        """``max_block_s``: blocks longer than this (data time) are cut into pieces; None: the
        source's blocks as they come (blocks timed by a sample clock cannot be cut)."""
        self.source = source
        self.stages = list(stages)
        self.max_samples = None if max_block_s is None else max(1, int(max_block_s * max(rate_hz, 1.0)))
        self.stats = PipelineStats()

    def _fraction(self) -> Optional[float]:
        f = getattr(self.source, "progress", None)
        try:
            return float(f()) if callable(f) else None
        except Exception:
            return None

    def run(self, progress: Optional[Callable[[PipelineStats], None]] = None) -> PipelineStats:
        """Run the source to its end through every stage; ``progress(stats)`` after each block."""
        st = self.stats
        t0 = time.perf_counter()
        for block in self.source:
            for piece in split_block(block, self.max_samples):
                if piece.n == 0:
                    continue
                st.samples += piece.n
                st.blocks += 1
                if st.first_ns is None:
                    st.first_ns = int(piece.time_at(0))
                st.last_ns = int(piece.time_at(piece.n - 1))
                st.segments.add(piece.segment)
                for stage in self.stages:
                    stage.push(piece)
            if progress is not None:
                st.wall_s = time.perf_counter() - t0
                st.fraction = self._fraction()
                progress(st)
        for stage in self.stages:
            stage.flush()
        st.wall_s = time.perf_counter() - t0
        return st
