"""The taps a run hangs on its output pass: the epoch and day tables (and what they carry:
sleep, rhythm, time use), written while the log is.

On one core both halves of the tables run here (``engine.tables.TablesTap``). A run whose log
is written by a child process (engine/mcap/sinkproc.py) splits them (``ChildTables``): the
per-sample half (``EpochFeed``: anglez, nonwear, steps) stays on the engine's thread, which has
the samples, and the epoch-level half (``EpochTableWriter``: the table text and its gzip, days,
sleep, rhythm, windows) runs in the child beside the log, given the rows and steps in the order
a one-core run hands them over. The child's sink runs the sink's calls in the order the engine
makes them, the writer's among them: the tables and the log (the sleep messages it writes at
close among its records) are the same bytes as on one core."""

from __future__ import annotations



def add_tables(output, ctx, src, *, corrected: bool, calibration_source: str) -> None:
    """Add the table writer (``engine.tables.TablesTap``, or ``ChildTables`` when the log is
    written by a child process) to ``output`` when the run writes tables (``ctx.tables``)."""
    if ctx.tables is None:
        return
    from ..tables import TablesTap
    s = ctx.settings
    tap = ChildTables if ctx.sink_process is not None else TablesTap
    output.taps.append(tap(ctx.tables, ctx.rate_hz, s.epoch_s, ctx.band, src, src.info,
                           sink=output.sink, extras=output.extras.keys,
                           corrected=corrected, calibration_source=calibration_source))


def writer_modules(ts) -> list:
    """The modules the tables' writer (``EpochTableWriter``) of ``ts`` imports, some only when
    it closes (the rhythm table's fits: scipy.optimize, ~0.4 s in a process without scipy): a
    log's child imports them while the engine's first pass runs (``SinkProcess.preload``)."""
    names = ["stillpoint.engine.tables.writer"]
    if ts.sleep is not None:
        names.append("stillpoint.engine.sleep.tap")
    if ts.outcomes.active and ts.outcomes.impute:
        names.append("stillpoint.engine.outcomes.impute")
    if ts.rhythm_path is not None:
        names += ["stillpoint.engine.rhythm.table", "stillpoint.engine.timeuse.levels",
                  "scipy.optimize", "scipy.special"]
        if ts.sleep is not None and ts.windows_path is not None:
            names.append("stillpoint.engine.timeuse.table")
    return names


class _WriterInChild:
    """``EpochFeed``'s writer: each call handed to the writer built in the log's child."""

    def __init__(self, remote):
        self.remote = remote

    def rows(self, rows) -> None:
        self.remote.call("rows", rows)

    def advance(self, step_times: dict, final_before_ns) -> None:
        self.remote.call("advance", step_times, final_before_ns)

    def finish(self, step_times: dict) -> None:
        self.remote.call("finish", step_times)


class ChildTables:
    """``TablesTap``'s interface for a run whose log is written by a child process (module
    docstring): the ``EpochFeed`` here, the ``EpochTableWriter`` built in the child (``sink``: a
    ``RemoteSink``). A table the child cannot write fails as the log's calls do there: raised,
    as the writer raised it, at the engine's next call; aborting the log aborts the tables."""

    def __init__(self, ts, rate_hz: float, epoch_s: float, band, source, info,
                 sink, extras=(), *, corrected: bool = True, calibration_source: str = ""):
        from ..core.outputs import check_output_path
        from ..tables.writer import EpochFeed, EpochTableWriter, writer_options
        check_output_path(ts.epochs_path, what="epoch table")  # the run's first checks, here
        check_output_path(ts.days_path, what="day table")
        self.feed = EpochFeed(ts, rate_hz, epoch_s, band, source, info, extras)
        self.remote = sink.attach("tables", EpochTableWriter, ts, epoch_s,
                                  **writer_options(info, extras), corrected=corrected,
                                  calibration_source=calibration_source)
        self.writer = _WriterInChild(self.remote)

    def push(self, block, batches, metrics, extras=None) -> None:
        """One step: the epoch rows it makes final go to the child's writer."""
        self.feed.push(self.writer, block, batches, metrics, extras)

    def flush(self, metrics=None, extras=None) -> None:
        """The end of the stream: the last rows and steps go to the child's writer."""
        self.feed.flush(self.writer, metrics, extras)

    def close(self, calibration_status: str = "") -> dict:
        """Close the tables in the child; return the tables summary it made."""
        return self.remote.ask("close", calibration_status, self.feed.assembly())

    def abort(self) -> None:
        """Drop the partial tables (the child's abort of the log does it too)."""
        try:
            self.remote.call("abort")
        except Exception:  # the child failed or ended: its tables went with the log
            pass
