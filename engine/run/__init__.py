"""The per-file job, ``process_file(input, out, settings) -> summary``, as small modules:

* ``inputs``: ``open_input`` sniffs the input once, resolves the zone of its times once
  (``ClockZone``) and opens it; later passes reopen it (``RunInput.open``);
* ``features``: the window-feature stage (pass 1 of a batch run; an online run's calibrator);
* ``output``: the one output pass (correction -> epoch metrics -> counts/MIMS -> taps) and the
  run's output stage, which logs it to MCAP;
* ``batch``, ``online``: each mode's schedule (when the calibration is fitted and applied);
* ``taps``, ``static``: the tables hung on the output pass; a static calibration's use;
* ``summary``: the run summary; ``tuning``: the run's tuning constants, one line each (read and
  set as ``tuning.NAME``: a copy of one made here would not change a run);
* ``job``: ``process_file`` itself (checks, the schedule, the end of the log).

Modes (same operators, different schedules): ``batch`` (two passes: fit, then correct) and
``online`` (one pass, refit every 12 h of data): see ``batch`` and ``online``.
"""

from __future__ import annotations

# the settings of a run live beside it; callers take them from here with process_file
from ..settings import RunSettings
from .context import chunk_span
from .features import FeatureStage
from .inputs import ClockZone, OpenedInput, RunInput, open_input
from .job import OutputError, check_output, process_file
from .output import OutputPass, OutputStage

__all__ = [
    "process_file", "RunSettings", "OutputError", "check_output", "open_input", "RunInput",
    "OpenedInput", "ClockZone", "FeatureStage", "OutputPass", "OutputStage", "chunk_span",
]
