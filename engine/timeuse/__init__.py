"""GGIR part 5's time use per window (wake-to-wake, midnight-to-midnight, onset-to-onset):
``windows.time_use`` computes the rows, ``table`` writes ``<stem>.windows.csv``; ``rules`` cites
every rule's source."""

from .windows import WINDOW_COLUMNS, time_use

__all__ = ["WINDOW_COLUMNS", "time_use"]
