"""The optional epoch metrics of a run, side by side: ActiLife counts (``RunSettings.counts``) and
MIMS-units (``RunSettings.mims``). ``push(batches)`` -> ``{"counts": EpochCounts, "mims":
EpochMims}`` of the epochs each completed (only the metrics switched on; ``{}`` when none is).
"""

from __future__ import annotations


class ExtraMetrics:
    def __init__(self, settings, rate_hz: float, range_g=None):
        self.ops = {}
        if getattr(settings, "counts", None):
            from .counts import CountsOperator
            self.ops["counts"] = CountsOperator(rate_hz, settings.epoch_s, settings.counts)
        if getattr(settings, "mims", False):
            from .mims import MimsOperator
            self.ops["mims"] = MimsOperator(rate_hz, settings.epoch_s, range_g)

    @property
    def keys(self) -> tuple:
        return tuple(self.ops)

    def push(self, batches) -> dict:
        if not self.ops:
            return {}
        out = {}
        for k, op in self.ops.items():
            parts = [op.push(b) for b in batches]
            out[k] = type(parts[0]).concat(parts) if parts else None
        return {k: v for k, v in out.items() if v is not None}

    @property
    def near_range_epochs(self) -> int:
        """MIMS epochs holding near-range samples, extrapolated (0 without MIMS)."""
        op = self.ops.get("mims")
        return op.near_range_epochs if op is not None else 0

    @property
    def unextrapolated_epochs(self) -> int:
        """MIMS epochs holding near-range samples left as recorded (0 without MIMS)."""
        op = self.ops.get("mims")
        return op.unextrapolated_epochs if op is not None else 0

    def flush(self) -> dict:
        return {k: op.flush() for k, op in self.ops.items()}
