"""The taps a run hangs on its output pass: the epoch and day tables (and what they carry:
sleep, rhythm, time use), written while the log is."""

from __future__ import annotations


def add_tables(output, ctx, src, *, corrected: bool, calibration_source: str) -> None:
    """Add the table writer (``engine.tables.TablesTap``) to ``output`` when the run writes
    tables (``ctx.tables``)."""
    if ctx.tables is None:
        return
    from ..tables import TablesTap
    s = ctx.settings
    output.taps.append(TablesTap(ctx.tables, ctx.rate_hz, s.epoch_s, ctx.band, src, src.info,
                                 sink=output.sink, extras=output.extras.keys,
                                 corrected=corrected, calibration_source=calibration_source))
