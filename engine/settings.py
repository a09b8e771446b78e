"""The settings of a run: ``RunSettings`` (everything that determines a run's output, logged as
the MCAP ``settings`` record), ``settings_problem(d)`` (the first unusable value of such a record,
checked when it is read). Plain data, read by the run and by the readers of its log (``engine/mcap/replay.py``)
without importing the run itself.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields
from typing import Optional

from stillpoint.engine.core.errors import StillpointError

from .calibration.schedule import CHUNK_HOURS, FIRST_HOURS
from .calibration.select import MAX_ABS_MEAN_G, SD_THRESHOLD_G
from .calibration.validate import validate_estimate
from .mcap.writer import CHUNK_SIZE, ZSTD_LEVEL
from .operators.counts import COUNT_MODES
from .operators.filters import BFEN_BAND_GGIR
from .operators.metrics import EPOCH_S
from .operators.windows import WINDOW_S

# default rate of the plottable view topic. A view sample costs ~75 bytes of MCAP (28 B payload,
# 31 B record header, 16 B index entry; zstd keeps ~half of the first two): at 1 Hz ~26 MB a
# week, ~11 % of a 7-day 100 Hz log (2 Hz: 53 MB), still 86,400 points a day for a plot.
VIEW_HZ = 1.0

# Bounds of every setting that sets how much is held in memory or how much work a run does,
# (low, high, unit), both inclusive: the one place they are kept. The command line's options
# are parsed with these (tools/cli/commands/_runopts.py) and a logged settings record is checked
# against them (``settings_problem``), so a run's memory stays flat within them:
# - ``window_s``/``epoch_s``: each operator's ring holds 2x one window/epoch of samples
#   (operators/base.py ring_capacity): 900 s at 3,200 Hz is 5.8 M samples (~140 MB), at
#   100 Hz 4 MB; 1 s is the shortest epoch of the reference tools (ActiLife counts).
# - ``flush_every_s``: a cell's corrected samples wait in the sink until the cell ends, and a
#   pipeline step is cut into cells; below 1 s a message holds less than one .cwa sector.
# - ``max_block_s``: one pipeline step's samples are in memory at once; per-step overhead
#   below 1 s.
# - ``chunk_s``: chunks span whole cells; ``chunk_size`` caps the uncompressed chunk in memory.
# - ``first_hours``/``chunk_hours``: one refit per ``chunk_hours`` of data (at 0.25 h, 672 fits
#   for 7 days).
# - ``view_hz``: view samples per second (0 = off).
BOUNDS = {
    "window_s": (1.0, 900.0, "s"),
    "epoch_s": (1.0, 900.0, "s"),
    "flush_every_s": (1.0, 600.0, "s"),
    "max_block_s": (1.0, 3600.0, "s"),
    "chunk_s": (1.0, 86_400.0, "s"),
    "first_hours": (0.25, 8760.0, "h"),
    "chunk_hours": (0.25, 8760.0, "h"),
    "chunk_size": (1024, 64 << 20, "bytes"),
    "view_hz": (0.001, 5000.0, "Hz"),
}


# What a run's MCAP keeps: "full" (every stream) or "lean": settings, estimates, QC, epoch metrics
# (with each epoch's mean temperature), sleep and the view stream, without the per-sample
# topics (LEAN_DROPPED, engine/mcap/sink.py); the recording itself is the raw copy, and
# `stillpoint replay LOG --raw RECORDING --log full` rebuilds the full log from it bit for bit.
LOG_KINDS = ("full", "lean")


def is_lean(settings) -> bool:
    """Whether a settings record (``RunSettings.to_dict`` form) is a lean log's."""
    return isinstance(settings, dict) and settings.get("log") == "lean"


class SettingsError(StillpointError, ValueError):
    """A run setting outside its bounds (``BOUNDS``) or of the wrong kind."""


def bound_problem(key: str, v) -> Optional[str]:
    """Why ``v`` is not a usable value of the bounded setting ``key`` ("key is v, expected ..."),
    or None. ``view_hz`` may also be 0 (off), ``chunk_s`` None (the engine's default)."""
    import math
    lo, hi, unit = BOUNDS[key]
    integer = key == "chunk_size"
    if (key == "view_hz" and v == 0 and not isinstance(v, bool)) or (key == "chunk_s" and v is None):
        return None
    ok = (isinstance(v, int) if integer else isinstance(v, (int, float))) and not isinstance(v, bool)
    ok = ok and math.isfinite(v) and lo <= v <= hi
    if ok:
        return None
    what = "an integer" if integer else "a number"
    extra = " (or 0: off)" if key == "view_hz" else (" (or null)" if key == "chunk_s" else "")
    return f"{key} is {v!r}, expected {what} in [{lo:g}, {hi:g}] {unit}{extra}"


@dataclass
class RunSettings:
    """Everything that determines a run's output (logged as the MCAP ``settings`` record)."""

    mode: str = "batch"  # "batch" | "online"
    window_s: float = WINDOW_S
    min_fill: float = 0.9  # a window needs this fraction of its nominal samples
    sd_threshold_g: float = SD_THRESHOLD_G
    max_abs_mean_g: float = MAX_ABS_MEAN_G
    epoch_s: float = EPOCH_S
    bfen_band_hz: tuple = BFEN_BAND_GGIR
    first_hours: float = FIRST_HOURS
    chunk_hours: float = CHUNK_HOURS
    temperature: bool = True  # fit the temperature term when the channel allows it
    ggir_compatible: bool = False
    calibrate: bool = True  # False: identity (raw g) on /corrected/accel
    prior: Optional[dict] = None  # online: estimate in force before the first accepted refit
    # a six-orientation static calibration (method "static-6" estimate) applied instead of the
    # autocalibration (never both): batch applies it from the start, online keeps it (refits
    # are logged, not applied)
    static_calibration: Optional[dict] = None
    corrected_quantum_g: float = 2.0 ** -16  # /corrected/accel rounding before float32 (0: none)
    max_block_s: float = 600.0  # pipeline block bound (data time): memory vs per-block overhead
    flush_every_s: float = 10.0  # MCAP flush cadence (data time)
    compression: str = "zstd"
    zstd_level: int = ZSTD_LEVEL  # 1: ~30 % less compression CPU than 3 for ~5 % more bytes
    chunk_size: int = CHUNK_SIZE
    view_hz: float = VIEW_HZ  # /view/accel samples per second (0: no view topic)
    chunk_s: Optional[float] = None  # MCAP chunk span, data time (None: CHUNK_S below)
    timezone: Optional[str] = None  # the device clock's zone (IANA or offset); None: as the reader
    # a GENEActiv header's zone that ``timezone`` contradicts is refused unless this is set
    # (engine/timezones.py, check_header_zone); the settings record keeps that it was
    timezone_override: bool = False
    # ActiLife counts per epoch (engine/operators/counts.py): None (off), "normal" or "lfe" (the
    # low-frequency extension); they need a whole-second epoch
    counts: Optional[str] = None
    mims: bool = False  # MIMS-units per epoch (engine/operators/mims.py)
    # what the MCAP keeps (LOG_KINDS): "full", or "lean" without the per-sample streams (raw,
    # gyro, the raw pages' temperature, corrected); a lean log's record says ``"log": "lean"``,
    # a full log's has no ``log`` key (as every log written before lean logs existed)
    log: str = "full"

    def __post_init__(self):
        if self.mode not in ("batch", "online"):
            raise ValueError(f"mode must be 'batch' or 'online', not {self.mode!r}")
        if self.log not in LOG_KINDS:
            raise ValueError(f"log must be one of {', '.join(LOG_KINDS)}, not {self.log!r}")
        if self.counts is not None and self.counts not in COUNT_MODES:
            raise ValueError(f"counts must be one of {', '.join(COUNT_MODES)}, not {self.counts!r}")
        if (self.counts or self.mims) and float(self.epoch_s) != int(self.epoch_s):
            raise ValueError(f"counts and MIMS-units need a whole-second epoch, not {self.epoch_s:g} s")
        self.bfen_band_hz = tuple(float(x) for x in self.bfen_band_hz)
        for key in BOUNDS:
            problem = bound_problem(key, getattr(self, key))
            if problem:
                raise SettingsError(f"settings: {problem}")

    def to_dict(self) -> dict:
        d = asdict(self)
        d["bfen_band_hz"] = list(self.bfen_band_hz)
        if d["log"] == "full":  # the default: full logs' settings records stay as they were
            del d["log"]
        return d

    @staticmethod
    def from_dict(d: dict, **overrides) -> "RunSettings":
        known = {f.name for f in fields(RunSettings)}
        kw = {k: v for k, v in d.items() if k in known}
        kw.update({k: v for k, v in overrides.items() if v is not None})
        return RunSettings(**kw)


def settings_problem(d: dict) -> Optional[str]:
    """The first value of a settings record (``RunSettings.to_dict`` form, e.g. the ``settings``
    metadata of an MCAP log) that a run cannot take, as "key: why"; None when every value is
    usable. Keys a RunSettings does not have are ignored; a missing key keeps its default. Every
    value is checked here, when the record is read, so a damaged record is one clear line and
    never a type error deep in the engine."""
    import math
    from .mcap.writer import COMPRESSIONS

    def num(v) -> bool:
        return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)

    def within(lo: float, hi: float, unit: str):  # (lo, hi]: the command line's ranges
        return (lambda v: num(v) and lo < v <= hi), f"a number in ({lo:g}, {hi:g}] {unit}"

    rules = {key: ((lambda v, key=key: bound_problem(key, v) is None), None) for key in BOUNDS}
    rules.update({"sd_threshold_g": within(0, 1, "g"), "max_abs_mean_g": within(0, 1000, "g")})
    rules.update({
        "mode": (lambda v: v in ("batch", "online"), "'batch' or 'online'"),
        "min_fill": (lambda v: num(v) and 0 < v <= 1, "a fraction in (0, 1]"),
        "bfen_band_hz": (lambda v: isinstance(v, (list, tuple)) and len(v) == 2
                         and all(num(x) for x in v) and 0 <= v[0] < v[1], "[low, high] in Hz"),
        "temperature": (lambda v: isinstance(v, bool), "true or false"),
        "ggir_compatible": (lambda v: isinstance(v, bool), "true or false"),
        "calibrate": (lambda v: isinstance(v, bool), "true or false"),
        "corrected_quantum_g": (lambda v: num(v) and 0 <= v <= 1, "a step in g in [0, 1]"),
        "compression": (lambda v: v in COMPRESSIONS, "one of " + ", ".join(COMPRESSIONS)),
        "zstd_level": (lambda v: isinstance(v, int) and not isinstance(v, bool) and 1 <= v <= 22,
                       "an integer zstd level 1..22"),
        "timezone": (lambda v: v is None or (isinstance(v, str) and 0 < len(v) <= 64), "null or a zone name"),
        "timezone_override": (lambda v: isinstance(v, bool), "true or false"),
        "counts": (lambda v: v is None or v in COUNT_MODES, "null, " + " or ".join(COUNT_MODES)),
        "mims": (lambda v: isinstance(v, bool), "true or false"),
        "log": (lambda v: v in LOG_KINDS, " or ".join(repr(k) for k in LOG_KINDS)),
    })
    if not isinstance(d, dict):
        return f"not a JSON object ({type(d).__name__})"
    for key, (ok, what) in rules.items():
        if key in d and not ok(d[key]):
            return bound_problem(key, d[key]) if what is None else f"{key} is {d[key]!r}, expected {what}"
    if (d.get("counts") or d.get("mims")) and not float(d.get("epoch_s", EPOCH_S)).is_integer():
        return f"epoch_s is {d.get('epoch_s')!r}, expected whole seconds with counts or MIMS-units"
    for key in ("prior", "static_calibration"):
        v = d.get(key)
        if v is None:
            continue
        try:
            validate_estimate(v, key)
        except StillpointError as e:
            return str(e)
    return None
