"""Sleep as GGIR computes it, on the 5 s epoch stream: sustained inactivity bouts (``sib``), the
HDCZA sleep-period window (``hdcza``), nights with GGIR's windows, guiders and daysleeper rule
(``nights``), GGIR's sleep-log formats (``diary``) and the nights table (``table``). Every
rule's source is listed in ``rules``.

API: ``SleepOptions``, ``SleepStage`` (fed epoch rows by ``engine.tables.TablesTap``),
``read_sleep_log``, ``hdcza``, ``SibStream``, ``nights_path``.
"""

from .diary import SleepLog, SleepLogError, read_sleep_log
from .hdcza import HdczaOptions, SptEstimate, hdcza
from .nights import Night, SleepOptions, SleepStage
from .sib import SibStream
from .table import NIGHT_COLUMNS, nights_path

__all__ = ["SleepLog", "SleepLogError", "read_sleep_log", "HdczaOptions", "SptEstimate", "hdcza",
           "Night", "SleepOptions", "SleepStage", "SibStream", "NIGHT_COLUMNS", "nights_path"]
