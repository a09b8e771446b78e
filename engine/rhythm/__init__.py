"""Rest-activity rhythm and sleep regularity as GGIR computes them: IS, IV and phi (``g.IVIS``),
cosinor and extended cosinor (ActCR through GGIR's ``cosinor_IS_IV_Analyses``), M10/L5 of the
average day and relative amplitude, the sleep regularity index (``CalcSleepRegularityIndex``)
and transition probabilities (``g.fragmentation``). ``metrics``: the pure functions; ``series``:
one recording's row; ``table``: the streaming collector and ``<stem>.rhythm.csv``; ``rules``:
every rule's source.
"""

from .series import RHYTHM_COLUMNS, rhythm_row

__all__ = ["RHYTHM_COLUMNS", "rhythm_row"]
