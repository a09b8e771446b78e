"""Epidemiology tables from the output pass: the epoch table (one flagged row per epoch, gaps
included) and the day table (local calendar days, valid-day rule, intensity minutes, M10/L5).

API: ``TablesSettings``, ``TablesTap`` (hooked into ``engine.run.process_file(tables=...)``),
``table_paths(mcap)``, and the parts ``EpochAssembler``, ``DayAccumulator``.
"""

from .days import DayAccumulator, day_columns
from .epochs import EpochAssembler, EpochRows, filter_warmup_s
from .writer import EPOCH_COLUMNS, TablesSettings, TablesTap, table_paths

__all__ = ["DayAccumulator", "day_columns", "EpochAssembler", "EpochRows", "filter_warmup_s",
           "EPOCH_COLUMNS", "TablesSettings", "TablesTap", "table_paths"]
