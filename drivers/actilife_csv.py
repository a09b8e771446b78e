"""ActiLife's raw CSV layout, written from a ``.gt3x`` (``stillpoint export FILE.gt3x --actilife``).

The layout ActiLife writes for a raw export: ten header lines, the column line
``Accelerometer X,Accelerometer Y,Accelerometer Z`` and one row per sample, CR LF line ends.
Each value is the stored integer / scale rounded half away from zero to 3 decimals, written
without trailing zeros (``-1``, ``0.214``) ([ALF] in drivers/constants.py). The rows run from
info.txt's ``Start Date`` (the header's start; rows carry no times):

* samples as the reader returns them; idle-sleep seconds repeat the last sample ([ALF]);
* a missing second (before the first record, between segments, after a USB-connect record) is
  zeros, as is every second from the log's last second with samples to the download time
  (log.bin layout; [ALF]). The legacy layout has no record times: its rows are its samples.
  A run of zeros longer than ``MAX_ZERO_RUN_S`` (a damaged clock or download time) is cut there
  and the cut is counted (``zero_seconds_cut``; the command says so).

The first header line names the ActiLife version whose layout this is (``ActiLife v6.13.4``, the
version that wrote the reference export we compare with), because readers of these files parse
that line (the device name, the rate from ``at 30 Hz``).
"""

from __future__ import annotations

import datetime as _dt
from typing import Optional

import numpy as np

from .gt3x import Gt3xReader, scale_round_half_away

ACTILIFE_LAYOUT_VERSION = "6.13.4"  # the export checked byte for byte (data/real PROVENANCE.md)
# ActiLife's device names in the first header line; GT3XPlus -> "GT3X+" is in the reference
# export, the others follow the device names of [GT3X] README.md 9-16 (not checked on an export)
DEVICE_NAMES = {"GT3XPlus": "GT3X+", "ActiSleepPlus": "ActiSleep+", "wGT3XPlus": "wGT3X+",
                "wGT3XBT": "wGT3X-BT", "wActiSleepPlus": "wActiSleep+", "wActiSleepBT": "wActiSleep-BT",
                "Link": "GT9X Link"}
COLUMN_LINE = "Accelerometer X,Accelerometer Y,Accelerometer Z"
EOL = "\r\n"
MODE_RAW = 12  # "Mode = 12" of the reference raw export


TABLE_KMAX = 200_000  # values of +-200 g at 3 decimals come from one table; larger ones one by one
MAX_ZERO_RUN_S = 31 * 86400  # a run of zero rows (a gap, the padding to the download) is cut here


def _text(v: int) -> str:
    a = abs(v)
    whole, frac = divmod(a, 1000)
    s = str(whole) if frac == 0 else f"{whole}.{frac:03d}".rstrip("0")
    return ("-" + s) if v < 0 else s


_TABLES: dict = {}  # kmax -> value_table(kmax), grown in powers of two as values need


def _table(need: int):
    """(table, kmax) covering +-need thousandths, or (None, 0) beyond ``TABLE_KMAX``."""
    if need >= TABLE_KMAX:
        return None, 0
    kmax = 1 << max(10, int(need).bit_length())
    if kmax not in _TABLES:
        _TABLES[kmax] = value_table(kmax)
    return _TABLES[kmax], kmax


def value_table(kmax: int) -> np.ndarray:
    """Text of k thousandths for k in [-kmax, kmax] (index k + kmax): ``-1``, ``0.214``, ``0``."""
    k = np.arange(-kmax, kmax + 1)
    out = np.empty(k.shape[0], dtype=object)
    for i, v in enumerate(k.tolist()):
        out[i] = _text(v)
    return out


def _local(ns: Optional[int]) -> Optional[_dt.datetime]:
    if ns is None:
        return None
    return _dt.datetime(1970, 1, 1) + _dt.timedelta(microseconds=int(ns) // 1000)


def header_lines(src: Gt3xReader) -> list[str]:
    info = src.info
    h = info.header
    model = DEVICE_NAMES.get(h.get("model", ""), h.get("model", "") or "ActiGraph")
    start = _local(h.get("start_local_ns"))
    down = _local(h.get("download_local_ns"))

    def date(d):
        return "" if d is None else f"{d.month}/{d.day}/{d.year}"

    def time(d):
        return "" if d is None else d.strftime("%H:%M:%S")

    battery = h.get("info", {}).get("Battery Voltage", "")
    rate = int(info.sample_rate_nominal)
    return [
        f"------------ Data File Created By ActiGraph {model} ActiLife v{ACTILIFE_LAYOUT_VERSION} "
        f"Firmware v{info.firmware} date format M/d/yyyy at {rate} Hz  Filter Normal -----------",
        f"Serial Number: {info.device_id}",
        f"Start Time {time(start)}",
        f"Start Date {date(start)}",
        "Epoch Period (hh:mm:ss) 00:00:00",
        f"Download Time {time(down)}",
        f"Download Date {date(down)}",
        "Current Memory Address: 0",
        f"Current Battery Voltage: {battery}     Mode = {MODE_RAW}",
        "-" * 50,
        COLUMN_LINE,
    ]


def write_actilife_csv(src: Gt3xReader, f) -> dict:
    """Write the CSV of an open (not yet iterated) reader to text stream ``f``; return counts."""
    rate = src.rate
    scale = src.scale
    h = src.info.header
    f.write(EOL.join(header_lines(src)) + EOL)
    zero_row = "0,0,0" + EOL
    rows = {"samples": 0, "zero_rows": 0, "idle_rows": 0, "zero_seconds_cut": 0}
    start_ns = h.get("start_local_ns")
    next_s = None if start_ns is None else int(start_ns) // 10**9  # next second due (local)

    def zeros(seconds: int):
        if seconds > MAX_ZERO_RUN_S:  # a damaged clock or download time: never weeks of zeros
            rows["zero_seconds_cut"] += seconds - MAX_ZERO_RUN_S
            seconds = MAX_ZERO_RUN_S
        if seconds > 0:
            n = seconds * rate
            rows["zero_rows"] += n
            for a in range(0, n, 100_000):
                f.write(zero_row * min(100_000, n - a))

    for b in src:
        secs = b.unit_sequence
        if next_s is None:
            next_s = int(secs[0])
        if src.layout == "log.bin" and int(secs[0]) > next_s:
            zeros(int(secs[0]) - next_s)
        k = scale_round_half_away(b.accel, scale)
        table, kmax = _table(int(np.abs(k).max(initial=0)))
        if table is not None:
            txt = table[k + kmax]
        else:  # beyond the table (a tiny scale): value by value
            u, inv = np.unique(k, return_inverse=True)
            txt = np.array([_text(v) for v in u.tolist()], dtype=object)[inv.reshape(k.shape)]
        lines = EOL.join(map(",".join, zip(txt[:, 0], txt[:, 1], txt[:, 2])))
        f.write(lines + EOL)
        rows["samples"] += b.n
        rows["idle_rows"] += int(b.per_sample["idle_sleep"].sum())
        next_s = int(secs[-1]) + 1
    if src.layout == "log.bin" and next_s is not None:
        down = h.get("download_local_ns")
        if down is not None:
            zeros(int(down) // 10**9 - next_s)
    rows["rows"] = rows["samples"] + rows["zero_rows"]
    return rows
