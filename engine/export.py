"""A recording's per-sample values to CSV or NPZ, or what a stillpoint log holds (a topic, a table):
``export_recording`` (the ``stillpoint export`` command calls it).

Columns (what users of cwa-convert / OMGui expect, in SI-ish units):

* ``time``: UTC. CSV ``time_format="iso"`` (default; ``--time`` on the command line) writes ISO 8601 with microseconds and a ``Z``
  (``2019-02-26T10:55:06.000500Z``; the sub-microsecond part is truncated), ``"epoch"`` writes
  Unix seconds with 9 decimals (exact), ``"ns"`` integer nanoseconds (exact). NPZ always holds
  ``time_ns`` (int64). When the zone is unknown (a .cwa without ``--timezone``) the times are the
  device clock, not UTC: the CSV column is ``time_local`` (ISO text without ``Z``; seconds or
  nanoseconds of the device clock read as if UTC; engine/timezones.py: one rule for every
  output). NPZ keeps ``time_ns`` and says which in ``info`` (``timezone``; ``timezone_offset_s``
  null when the zone is unknown).
* ``x, y, z``: acceleration in g (6 decimals in CSV; float64 in NPZ as ``accel`` (n, 3)).
* ``gx, gy, gz``: angular rate in deg/s (AX6 only; ``gyro`` (n, 3) in NPZ).
* ``temperature``: degC, the sector/page value held over its samples (no interpolation).
* ``light``: lux (AX: 10^((raw+512)*6/1024); GENEActiv: raw * Lux / Volts of the header).
* ``battery``: volts, per sector/page, held.
* ``button`` (GENEActiv only): the per-sample button bit.
* ``idle_sleep`` (ActiGraph .gt3x only): 1 where the device was in idle sleep (the reader repeats
  its last sample over those seconds, as ActiLife does).

``export_actilife`` (``--actilife``: a .gt3x input, CSV output) writes ActiLife's own raw CSV layout instead
(drivers/actilife_csv.py): its header lines and ``Accelerometer X,Accelerometer Y,Accelerometer Z``
rows, the same bytes ActiLife writes for the public reference file.
NPZ also holds ``segment`` (int32: continuous-logging stretch of each sample) and ``info`` (a JSON
string: device, header fields, QC log).

Streaming: CSV text is formatted with numpy block by block (no per-sample Python) and written as it
goes; NPZ columns are streamed to temporary files next to the output and then copied into the zip,
so memory stays flat however long the recording. The output appears under its name only when
complete (written as ``OUT.part`` and renamed; see ``stillpoint.engine.core.outputs``).

An MCAP input (a run's log) takes ``topics`` (``stillpoint.engine.mcap.export.export_mcap``) or
``table`` = ``epochs``, ``days`` or ``nights`` (``stillpoint.engine.workflows.tables_from_mcap``:
the tables of the run's estimate applied from the first sample, sleep as the run computed it;
``nights`` computes sleep with the run's settings, or the defaults when the run computed none);
one of them is required: the output's name never decides what is written.
"""

from __future__ import annotations

import gzip
import io
import json
import os
import shutil
import tempfile
import zipfile
from pathlib import Path
from typing import Optional

import numpy as np

from stillpoint.drivers import sniff_format
from stillpoint.drivers.constants import cwa_light_lux, gna_light_lux
from stillpoint.engine.core.blocks import PER_SAMPLE_BUTTON, PER_SAMPLE_IDLE_SLEEP, PER_SAMPLE_LIGHT_RAW
from stillpoint.engine.core.errors import StillpointError
from stillpoint.engine.core.outputs import atomic_output, check_output_path

from .inspection import reader_zone
from .recordings import open_recording

TIME_FORMATS = ("iso", "epoch", "ns")
TABLES = ("epochs", "days", "nights")  # what a table export of an MCAP input can be


# ---------------------------------------------------------------------------- per-sample columns
def block_columns(block, info) -> dict[str, np.ndarray]:
    """Per-sample export columns of one Block (float64 physical units)."""
    unit = block.unit_of_sample()
    cols = {"time_ns": block.time_ns, "accel": block.accel_g()}
    if block.gyro is not None:
        cols["gyro"] = block.gyro_dps()
    cols["temperature"] = block.temperature_c[unit].astype(np.float64)
    if info.device_type == "ActiGraph":  # lux per second, as the reader gives it
        cols["light"] = block.light[unit].astype(np.float64)
    elif PER_SAMPLE_LIGHT_RAW in block.per_sample and info.device_type == "GENEActiv":
        volts, lux = info.header.get("volts"), info.header.get("lux")
        raw = block.per_sample[PER_SAMPLE_LIGHT_RAW]
        cols["light"] = gna_light_lux(raw, lux, volts) if volts and lux else np.full(block.n, np.nan)
    else:
        cols["light"] = cwa_light_lux(block.light)[unit]
    cols["battery"] = block.battery_v[unit].astype(np.float64)
    if PER_SAMPLE_BUTTON in block.per_sample:
        cols["button"] = block.per_sample[PER_SAMPLE_BUTTON].astype(np.uint8)
    if PER_SAMPLE_IDLE_SLEEP in block.per_sample:
        cols["idle_sleep"] = block.per_sample[PER_SAMPLE_IDLE_SLEEP].astype(np.uint8)
    cols["segment"] = np.full(block.n, block.segment, np.int32)
    return cols


# ---------------------------------------------------------------------------- vectorised text
_DIGITS = np.arange(48, 58, dtype=np.uint8)


def _put_digits(m: np.ndarray, col: int, v: np.ndarray, k: int) -> None:
    """Write v (non-negative ints) as k zero-padded digits into m[:, col:col+k].

    Runs in int32 (numpy divides int32 by a constant far faster than int64); more than 9 digits
    are split into a high part and 8 low digits."""
    if k > 9:
        hi = v // 10**8
        _put_digits(m, col, hi, k - 8)
        _put_digits(m, col + k - 8, v - hi * 10**8, 8)
        return
    v = np.asarray(v).astype(np.int32)
    for c in range(col + k - 1, col - 1, -1):
        q = v // 10
        m[:, c] = (v - q * 10).astype(np.uint8) + 48
        v = q


def format_fixed(v: np.ndarray, decimals: int) -> np.ndarray:
    """Numbers -> (n, w) uint8 ASCII with fixed decimals; 0 bytes mark unused cells (the caller
    drops them, so the text has no padding). NaN becomes an empty field."""
    v = np.asarray(v, np.float64)
    finite = np.isfinite(v)
    x = np.rint(np.where(finite, v, 0.0) * 10 ** decimals).astype(np.int64)
    m = format_scaled(x, decimals)
    m[~finite] = 0
    return m


def format_scaled(x: np.ndarray, decimals: int = 0) -> np.ndarray:
    """Integers x -> text of x / 10**decimals (exact, int64 arithmetic), as in ``format_fixed``."""
    x = np.asarray(x, np.int64)
    n = x.shape[0]
    neg = x < 0
    a = np.abs(x)
    scale = 10 ** decimals
    ip, fp = np.divmod(a, scale)
    k = max(1, len(str(int(ip.max())))) if n else 1
    width = 1 + k + (1 + decimals if decimals else 0)
    m = np.zeros((n, width), np.uint8)
    m[:, 0] = np.where(neg, ord("-"), 0)
    _put_digits(m, 1, ip, k)
    for j in range(k - 1):  # blank the leading zeros of the integer part
        m[:, 1 + j] *= ip >= 10 ** (k - 1 - j)
    if decimals:
        m[:, 1 + k] = ord(".")
        _put_digits(m, 2 + k, fp, decimals)
    return m


def _civil_from_days(days: np.ndarray):
    """Days since 1970-01-01 -> (year, month, day), proleptic Gregorian (H. Hinnant's algorithm)."""
    z = days + 719468
    era = np.floor_divide(z, 146097)
    doe = z - era * 146097
    yoe = (doe - doe // 1460 + doe // 36524 - doe // 146096) // 365
    doy = doe - (365 * yoe + yoe // 4 - yoe // 100)
    mp = (5 * doy + 2) // 153
    d = doy - (153 * mp + 2) // 5 + 1
    mo = np.where(mp < 10, mp + 3, mp - 9)
    y = yoe + era * 400 + (mo <= 2)
    return y, mo, d


def format_iso(t_ns: np.ndarray, utc: bool = True) -> np.ndarray:
    """UTC ns -> "YYYY-MM-DDTHH:MM:SS.ffffffZ" (27 bytes; sub-microsecond part truncated);
    ``utc=False``: a local time, the same text without the ``Z`` (26 bytes)."""
    t_us = np.floor_divide(np.asarray(t_ns, np.int64), 1000)
    days, us_of_day = np.divmod(t_us, 86_400_000_000)
    y, mo, d = _civil_from_days(days)
    sec, us = np.divmod(us_of_day, 1_000_000)
    hh, rem = np.divmod(sec, 3600)
    mi, ss = np.divmod(rem, 60)
    m = np.empty((t_us.shape[0], 27 if utc else 26), np.uint8)
    m[:, [4, 7]] = ord("-")
    m[:, 10] = ord("T")
    m[:, [13, 16]] = ord(":")
    m[:, 19] = ord(".")
    if utc:
        m[:, 26] = ord("Z")
    for col, v, k in ((0, np.clip(y, 0, 9999), 4), (5, mo, 2), (8, d, 2), (11, hh, 2), (14, mi, 2),
                      (17, ss, 2), (20, us, 6)):
        _put_digits(m, col, v, k)
    return m


def format_time(t_ns: np.ndarray, mode: str, utc: bool = True) -> np.ndarray:
    """The CSV time column's text of int64 ns times (``mode``: one of ``TIME_FORMATS``; ISO
    text ends in ``Z`` when ``utc``)."""
    t_ns = np.asarray(t_ns, np.int64)
    if mode == "iso":
        return format_iso(t_ns, utc)
    if mode == "epoch":
        return format_scaled(t_ns, 9)
    if mode == "ns":
        return format_scaled(t_ns, 0)
    raise ValueError(f"time format must be one of {TIME_FORMATS}")


class CsvSink:
    """CSV text written block by block (gzip when the name ends with .gz)."""

    DECIMALS = {"accel": 6, "gyro": 5, "temperature": 4, "light": 3, "battery": 4}

    def __init__(self, raw, time_format: str, gz: bool = False, utc: bool = True):
        """``raw``: the binary output file (left open on close); ``utc``: the zone is known (else
        the time column is ``time_local``, the device clock)."""
        self.time_format = time_format
        self.utc = utc
        self._raw = raw
        self._f = (gzip.GzipFile(fileobj=raw, mode="wb", compresslevel=6) if gz
                   else io.BufferedWriter(raw, 1 << 20))
        self._header_written = False
        self.rows = 0

    def write(self, cols: dict) -> None:
        """Append the rows of one block's columns (``block_columns``)."""
        n = cols["time_ns"].shape[0]
        if not self._header_written:
            names = ["time" if self.utc else "time_local", "x", "y", "z"]
            if "gyro" in cols:
                names += ["gx", "gy", "gz"]
            names += ["temperature", "light", "battery"]
            if "button" in cols:
                names.append("button")
            if "idle_sleep" in cols:
                names.append("idle_sleep")
            self._f.write((",".join(names) + "\n").encode())
            self._header_written = True
            self._names = names
        if n == 0:
            return
        parts = [format_time(cols["time_ns"], self.time_format, self.utc)]
        for j in range(3):
            parts.append(format_fixed(cols["accel"][:, j], self.DECIMALS["accel"]))
        if "gyro" in cols:
            for j in range(3):
                parts.append(format_fixed(cols["gyro"][:, j], self.DECIMALS["gyro"]))
        for key in ("temperature", "light", "battery"):
            parts.append(format_fixed(cols[key], self.DECIMALS[key]))
        if "button" in cols:
            parts.append(format_fixed(cols["button"], 0))
        if "idle_sleep" in cols:
            parts.append(format_fixed(cols["idle_sleep"], 0))
        comma = np.full((n, 1), ord(","), np.uint8)
        pieces = []
        for i, p in enumerate(parts):
            if i:
                pieces.append(comma)
            pieces.append(p)
        pieces.append(np.full((n, 1), ord("\n"), np.uint8))
        text = np.concatenate(pieces, axis=1).ravel()
        self._f.write(text[text != 0].tobytes())
        self.rows += n

    def close(self, info_dict: Optional[dict] = None) -> None:
        """Finish the file (the header of an empty export; ``info_dict`` is not written)."""
        if not self._header_written:
            self.write({"time_ns": np.zeros(0, np.int64), "accel": np.zeros((0, 3))})
        if isinstance(self._f, io.BufferedWriter):
            self._f.flush()
            self._f.detach()  # the output file stays open for its atomic commit
        else:
            self._f.close()


class NpzSink:
    """Columns streamed to temporary raw files, then packed as .npy members of a zip (np.load-able)."""

    def __init__(self, raw, folder: Path, compress: bool, utc: bool = True):
        """``raw``: the binary output file (left open on close); ``folder``: for column scratch
        files (beside the output, removed on close); ``utc``: the zone is known (``info``
        says which; ``time_ns`` keeps its name)."""
        self._raw = raw
        self.utc = utc
        self.compress = compress
        self._dir = tempfile.mkdtemp(prefix=".export-", dir=str(folder))
        self._files: dict[str, tuple] = {}  # name -> (file, dtype, trailing shape)
        self.rows = 0

    def write(self, cols: dict) -> None:
        """Append one block's columns to their temporary files."""
        for name, arr in cols.items():
            arr = np.ascontiguousarray(arr)
            if name not in self._files:
                f = open(os.path.join(self._dir, name + ".raw"), "wb")
                self._files[name] = (f, arr.dtype, arr.shape[1:])
            f, dtype, tail = self._files[name]
            if arr.dtype != dtype or arr.shape[1:] != tail:
                raise ValueError(f"column {name} changed dtype/shape between blocks")
            f.write(arr.tobytes())
        self.rows += cols["time_ns"].shape[0]

    def close(self, info_dict: Optional[dict] = None) -> None:
        """Pack the columns and ``info_dict`` (as ``info``) into the zip."""
        comp = zipfile.ZIP_DEFLATED if self.compress else zipfile.ZIP_STORED
        try:
            with zipfile.ZipFile(self._raw, "w", compression=comp, allowZip64=True) as zf:
                for name, (f, dtype, tail) in self._files.items():
                    f.close()
                    header = {"descr": np.lib.format.dtype_to_descr(dtype), "fortran_order": False,
                              "shape": (self.rows,) + tuple(tail)}
                    with zf.open(name + ".npy", "w", force_zip64=True) as dst:
                        np.lib.format.write_array_header_1_0(dst, header)
                        with open(f.name, "rb") as src:
                            shutil.copyfileobj(src, dst, 1 << 20)
                if info_dict is not None:
                    with zf.open("info.npy", "w") as dst:
                        np.lib.format.write_array(dst, np.array(json.dumps(info_dict, default=str)))
        finally:
            for f, _, _ in self._files.values():
                f.close()
            shutil.rmtree(self._dir, ignore_errors=True)


# ---------------------------------------------------------------------------- the job
def _output_kind(out: Path) -> str:
    name = out.name.lower()
    if name.endswith(".csv") or name.endswith(".csv.gz"):
        return "csv"
    if name.endswith(".npz"):
        return "npz"
    raise StillpointError(f"{out}: output must end with .csv, .csv.gz or .npz")


def export_mcap(path, out, topics):
    """The messages of an MCAP log's ``topics`` into ``out`` (engine/mcap/export.py)."""
    from .mcap.export import export_mcap as _export
    return _export(path, out, topics)


_KIND = {"cwa": "an AX3/AX6 .cwa", "geneactiv": "a GENEActiv .bin", "gt3x": "an ActiGraph .gt3x"}


def export_actilife(path, out, *, timezone=None, timezone_override: bool = False) -> dict:
    """ActiLife's raw CSV of a .gt3x (drivers/actilife_csv.py). Rows carry no times, so the zone
    only matters for the report."""
    from stillpoint.drivers.actilife_csv import write_actilife_csv
    out = Path(out)
    fmt = sniff_format(path)
    if fmt != "gt3x":
        raise StillpointError(f"{path}: --actilife writes ActiLife's CSV of an ActiGraph .gt3x; this "
                              f"input is {_KIND.get(fmt, fmt)}")
    if not out.name.lower().endswith(".csv"):
        raise StillpointError(f"{out}: --actilife writes a CSV: name it .csv")
    check_output_path(out)
    src = open_recording(path)
    try:
        with atomic_output(out, binary=False) as f:
            rows = write_actilife_csv(src, f)
    finally:
        src.close()
    return {"format": fmt, "output": str(out), "actilife": rows, "qc": src.qc.as_dict()}


def export_recording(path, out, *, time_format: str = "iso", timezone=None, compress: bool = False,
                     topics=None, table: Optional[str] = None,
                     table_options: Optional[dict] = None, timezone_override: bool = False,
                     progress=None) -> dict:
    """Export a recording to CSV or NPZ (see the module docstring). Returns a small report.
    ``progress(fraction=...)``: told the share of a recording read after each block.

    An MCAP input exports what is asked for, never what the output's name suggests: ``table``
    (``epochs``, ``days`` or ``nights``: that table, made from the log) or ``topics``; one of
    them is required. ``time_format``: ``iso``, ``epoch`` or ``ns`` (``TIME_FORMATS``)."""
    out = Path(out)
    fmt = sniff_format(path)
    if topics and fmt != "mcap":
        raise StillpointError(f"{path}: --topic selects the topics of a stillpoint MCAP log; this "
                              f"input is {_KIND.get(fmt, fmt)} recording, whose export has no "
                              "topics (leave --topic out)")
    if table and fmt != "mcap":
        raise StillpointError(f"{path}: --table makes a table from a stillpoint MCAP log; this "
                              f"input is {_KIND.get(fmt, fmt)} recording (run `stillpoint process` "
                              "on it: it writes both tables)")
    if fmt == "mcap":
        if topics and table:
            raise StillpointError(f"{path}: give either --table or --topic, not both")
        if not topics and not table:
            raise StillpointError(f"{path}: say what to export from the MCAP log: --table "
                                  "epochs|days|nights (a table) or --topic T (a topic's messages)")
    if table:
        if table not in TABLES:
            raise StillpointError(f"--table must be one of {', '.join(TABLES)}")
        result = _table_from_mcap(path, out, table, timezone, table_options or {})
        return {"format": "mcap", "output": str(out), "table": table, "tables": result}
    if fmt == "mcap":
        result = export_mcap(path, out, topics)
        return {"format": "mcap", "output": str(out), "result": result}
    kind = _output_kind(out)
    if time_format not in TIME_FORMATS:
        raise StillpointError(f"--time must be one of {', '.join(TIME_FORMATS)}")
    opts, zone = reader_zone(path, fmt, timezone, timezone_override)
    check_output_path(out)
    src = open_recording(path, **opts)
    if progress is not None:
        from stillpoint.engine.progress import Reporting
        src = Reporting(src, progress)
    sink = None
    try:
        with atomic_output(out) as raw:
            sink = (CsvSink(raw, time_format, gz=out.name.lower().endswith(".gz"), utc=zone.known)
                    if kind == "csv" else NpzSink(raw, out.parent, compress, utc=zone.known))
            for block in src:
                sink.write(block_columns(block, src.info))
            info = src.info
            info_dict = {"device_type": info.device_type, "device_id": info.device_id,
                         "session_id": info.session_id, "firmware": info.firmware,
                         "sample_rate_nominal": info.sample_rate_nominal,
                         "timezone_offset_s": info.timezone_offset_s if zone.known else None,
                         "timezone": zone.label, "metadata": info.metadata,
                         "header": {k: v for k, v in info.header.items()}, "qc": src.qc.as_dict()}
            sink.close(info_dict)
    finally:
        src.close()
        if isinstance(sink, NpzSink):
            shutil.rmtree(sink._dir, ignore_errors=True)
    return {"format": fmt, "output": str(out), "samples": sink.rows, "qc": src.qc.as_dict(),
            "timezone": zone.label}


def _table_from_mcap(path, out: Path, table: str, timezone, options: dict) -> dict:
    """One table (``epochs``: gzip CSV, ``days`` or ``nights``: CSV) from a log into ``out``; the
    others, which the same pass makes, go to hidden names beside it and are removed. ``nights``
    computes sleep with the run's logged settings, or the defaults when the run computed none."""
    import secrets

    from stillpoint.engine.workflows.tables_from_mcap import tables_from_mcap
    name = out.name.lower()
    if table == "epochs" and not name.endswith(".csv.gz"):
        raise StillpointError(f"{out}: the epoch table is gzip-compressed CSV: name it .csv.gz")
    if table in ("days", "nights") and not name.endswith(".csv"):
        raise StillpointError(f"{out}: the {table[:-1]} table is CSV: name it .csv")
    what = {"epochs": "epoch table", "days": "day table", "nights": "nights table"}[table]
    check_output_path(out, what=what)
    hidden = f".{out.name}.{secrets.token_hex(6)}."
    paths = {t: out if t == table else out.with_name(hidden + suffix)
             for t, suffix in (("epochs", "epochs.csv.gz"), ("days", "days.csv"),
                               ("nights", "nights.csv"))}
    opts = dict(options)
    if table == "nights":
        from stillpoint.engine.sleep import SleepOptions
        from stillpoint.engine.sleep.tap import logged_options
        from stillpoint.engine.mcap.stream import read_metadata
        with open(path, "rb") as f:
            meta = read_metadata(f)
        try:
            logged = json.loads((meta.get("summary") or {}).get("tables") or "null")
        except (TypeError, ValueError, RecursionError):
            logged = None
        opts["sleep"] = logged_options(logged) or SleepOptions()
    try:
        return tables_from_mcap(path, paths["epochs"], paths["days"], timezone=timezone,
                                nights_path=paths["nights"], **opts)
    finally:
        for t, p in paths.items():
            if t == table:
                continue
            for q in (p, p.with_name(p.name + ".part")):
                try:
                    os.unlink(q)
                except OSError:
                    pass
