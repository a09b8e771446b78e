"""The Operator protocol: an incremental, stateful stage of the pipeline.

``push(item) -> outputs`` consumes one input item (a Block, a corrected batch, a feature table)
and returns whatever became final because of it; ``flush() -> outputs`` returns what is still
pending at the end of the stream. The invariant every operator keeps (and is property-tested
for): the concatenated outputs do not depend on how the input stream was cut into items.
"""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable


@runtime_checkable
class Operator(Protocol):
    def push(self, item: Any) -> Any: ...

    def flush(self) -> Any: ...


def ring_capacity(width_s: float, rate_hz: float, minimum: int = 4096) -> int:
    """Samples a ring must hold for one bin of ``width_s`` at ``rate_hz`` (with 2x headroom)."""
    return max(minimum, int(2 * width_s * max(rate_hz, 1.0)) + 1024)
