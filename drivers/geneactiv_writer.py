"""GENEActiv ``.bin`` writer: produces real files (standard 59-line header + 300-sample pages)
for the simulator and the tests. Write -> ``GeneactivReader`` read is exact: same counts, light,
button, temperature/battery (as written, 1 and 4 decimals), times within 1 ms.

Timing: each page's ``Page Time`` is the local time (UTC + ``timezone``) of its first sample,
rounded to the millisecond (the format's resolution); the samples within a page are implied by
the page times, as on a device. Temperature and battery are per page: the page takes the value
at its first sample.

Partial last page: real devices write whole pages only. ``close()`` writes the remaining samples
(fewer than 300) as a last page whose data line is shorter (``partial_page="write"``, the default:
nothing written is lost; readers log it as ``truncated_page``), or drops them
(``partial_page="drop"``: every page whole, as a device would have written it).

``Number of Pages`` is patched into the header on ``close()``. A ``.gz`` path is written through a
temporary plain file and gzip-compressed on close.
"""

from __future__ import annotations

import gzip
import os
import shutil
from pathlib import Path
from typing import BinaryIO, Optional

import numpy as np

from .constants import GNA_LIGHT_SHIFT, GNA_RATE_85_7, GNA_SAMPLES_PER_PAGE
from .geneactiv_header import format_time_ms, format_timezone, parse_timezone

__all__ = ["GeneactivWriter"]

_HEX_DIGITS = np.frombuffer(b"0123456789ABCDEF", np.uint8)
_NPAGES_WIDTH = 12  # "Number of Pages:" value padded to this width so close() can patch it in place


def encode_hex_samples(accel, light, button) -> np.ndarray:
    """(n, 3) 12-bit counts, (n,) 10-bit light, (n,) button -> (n, 12) uint8 upper-case hex. [GNA] §5"""
    a = np.asarray(accel, np.int64) & 0xFFF
    low = ((np.asarray(light, np.int64) & 0x3FF) << GNA_LIGHT_SHIFT) | ((np.asarray(button, np.int64) & 1) << 1)
    v = (a[:, 0] << 36) | (a[:, 1] << 24) | (a[:, 2] << 12) | low
    shifts = np.arange(44, -1, -4, dtype=np.int64)
    return _HEX_DIGITS[(v[:, None] >> shifts[None, :]) & 0xF]


def _rate_texts(rate_hz: float) -> tuple[str, str]:
    """(header value, page value) of Measurement Frequency, e.g. ("85.7 Hz", "85.7")."""
    if abs(rate_hz - GNA_RATE_85_7) < 1e-9 or abs(rate_hz - 85.7) < 1e-9:
        return "85.7 Hz", "85.7"
    if float(rate_hz).is_integer():
        return f"{int(rate_hz)} Hz", f"{rate_hz:.1f}"
    return f"{rate_hz:g} Hz", f"{rate_hz:g}"


# The standard header layout [GNA] §2: (section, [(key, default value)]).
def _header_layout(w: "GeneactivWriter", start_text: str) -> list[tuple[str, list[tuple[str, str]]]]:
    return [
        ("Device Identity", [("Device Unique Serial Code", w.serial), ("Device Type", "GENEActiv"),
                             ("Device Model", w.model), ("Device Firmware Version", w.firmware),
                             ("Calibration Date", start_text)]),
        ("Device Capabilities", [("Accelerometer Range", "-8 to 8"), ("Accelerometer Resolution", "0.0039"),
                                 ("Accelerometer Units", "g"), ("Light Meter Range", "0 to 5000"),
                                 ("Light Meter Resolution", "5"), ("Light Meter Units", "lux"),
                                 ("Temperature Sensor Range", "0 to 70"),
                                 ("Temperature Sensor Resolution", "0.1"),
                                 ("Temperature Sensor Units", "deg. C")]),
        ("Configuration Info", [("Measurement Frequency", _rate_texts(w.rate_hz)[0]),
                                ("Measurement Period", "168 Hours"), ("Start Time", start_text),
                                ("Time Zone", format_timezone(w.timezone_offset_s))]),
        ("Trial Info", [("Study Centre", ""), ("Study Code", ""), ("Investigator ID", ""),
                        ("Exercise Type", ""), ("Config Operator ID", ""), ("Config Time", start_text),
                        ("Config Notes", ""), ("Extract Operator ID", ""), ("Extract Time", start_text),
                        ("Extract Notes", "")]),
        ("Subject Info", [("Device Location Code", ""), ("Subject Code", ""), ("Date of Birth", "1900-01-01"),
                          ("Sex", ""), ("Height", ""), ("Weight", ""), ("Handedness Code", ""),
                          ("Subject Notes", "")]),
        ("Calibration Data", [("x gain", str(w.gains[0])), ("x offset", str(w.offsets[0])),
                              ("y gain", str(w.gains[1])), ("y offset", str(w.offsets[1])),
                              ("z gain", str(w.gains[2])), ("z offset", str(w.offsets[2])),
                              ("Volts", str(w.volts)), ("Lux", str(w.lux))]),
        ("Memory Status", [("Number of Pages", "0".ljust(_NPAGES_WIDTH))]),
    ]


class GeneactivWriter:
    """Write a GENEActiv ``.bin`` file from raw 12-bit counts (see the module docstring).

    ``header_fields`` overrides values of the standard header by key (e.g. {"Subject Code": "P01",
    "Device Location Code": "left wrist"}); an unknown key is an error.
    """

    def __init__(self, path, *, serial: str = "012345", rate_hz: float = 100.0,
                 gains=(25600, 25600, 25600), offsets=(0, 0, 0), volts: int = 300, lux: int = 800,
                 timezone="+00:00", firmware: str = "Ver4.08a", model: str = "1.1",
                 start_time: Optional[int] = None, line_ending: str = "\r\n",
                 header_fields: Optional[dict] = None, partial_page: str = "write"):
        if line_ending not in ("\r\n", "\n"):
            raise ValueError("line_ending must be '\\r\\n' or '\\n'")
        if partial_page not in ("write", "drop"):
            raise ValueError("partial_page must be 'write' or 'drop'")
        if not rate_hz > 0:
            raise ValueError(f"rate_hz must be > 0, got {rate_hz}")
        self.path = Path(path)
        self.serial = str(serial)
        self.rate_hz = float(rate_hz)
        self.gains = tuple(int(g) for g in gains)
        self.offsets = tuple(int(o) for o in offsets)
        if len(self.gains) != 3 or len(self.offsets) != 3 or min(self.gains) <= 0:
            raise ValueError("gains (3 positive integers) and offsets (3 integers) required")
        self.volts, self.lux = volts, lux
        self.timezone_offset_s = parse_timezone(timezone)
        self.firmware, self.model = firmware, model
        self.start_time = start_time  # UTC ns for the header Start Time; default: first sample
        self.eol = line_ending.encode()
        self.header_fields = dict(header_fields or {})
        self.partial_page = partial_page
        known = {k for _, kv in _header_layout(self, "") for k, _ in kv}
        unknown = set(self.header_fields) - known
        if unknown:
            raise ValueError(f"unknown header field(s) {sorted(unknown)}; known: {sorted(known)}")
        self.pages_written = 0
        self.samples_written = 0
        self._gz = self.path.suffix == ".gz"
        self._plain = self.path.with_name(self.path.name + ".part") if self._gz else self.path
        self._f: Optional[BinaryIO] = None
        self._npages_pos: Optional[int] = None
        self._pending: list[tuple] = []  # (time_ns, accel, light, button, temp, batt) arrays
        self._pending_n = 0
        self._closed = False

    # ------------------------------------------------------------------ API
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def write(self, time_ns, raw_counts, *, light_raw=0, button=0, temperature_c=25.0,
              battery_v=4.0) -> None:
        """Append samples: time_ns (n,) int64 UTC; raw_counts (n, 3) integers in -2048..2047;
        light_raw 0..1023 and button 0/1 (scalar or per sample); temperature_c / battery_v scalar or
        per sample (a page stores the value at its first sample)."""
        if self._closed:
            raise ValueError("writer is closed")
        t = np.atleast_1d(np.asarray(time_ns, np.int64))
        a = np.asarray(raw_counts)
        n = t.shape[0]
        if a.shape != (n, 3):
            raise ValueError(f"raw_counts must have shape ({n}, 3), got {a.shape}")
        if n == 0:
            return
        if not np.issubdtype(a.dtype, np.integer):
            raise ValueError("raw_counts must be integers (12-bit counts)")
        if a.min() < -2048 or a.max() > 2047:
            raise ValueError("raw_counts outside the 12-bit range -2048..2047")
        light = np.broadcast_to(np.asarray(light_raw, np.int64), (n,))
        if light.min() < 0 or light.max() > 1023:
            raise ValueError("light_raw outside 0..1023 (10 bits)")
        btn = np.broadcast_to(np.asarray(button, np.int64), (n,))
        if btn.min() < 0 or btn.max() > 1:
            raise ValueError("button must be 0 or 1")
        temp = np.broadcast_to(np.asarray(temperature_c, np.float64), (n,))
        batt = np.broadcast_to(np.asarray(battery_v, np.float64), (n,))
        self._pending.append((t, a.astype(np.int64), light, btn, temp, batt))
        self._pending_n += n
        if self._pending_n >= GNA_SAMPLES_PER_PAGE:
            self._flush(final=False)

    def close(self) -> None:
        if self._closed:
            return
        try:
            self._flush(final=True)
            f = self._f if self._f is not None else self._open(None)
            assert self._npages_pos is not None  # the header layout always has Number of Pages
            f.seek(self._npages_pos)
            f.write(str(self.pages_written).ljust(_NPAGES_WIDTH).encode())
            f.close()
            if self._gz:
                with open(self._plain, "rb") as src, gzip.open(self.path, "wb", compresslevel=6) as dst:
                    shutil.copyfileobj(src, dst, 1 << 20)
                os.unlink(self._plain)
        finally:
            self._closed = True

    # ------------------------------------------------------------------ internals
    def _local_ms(self, t_ns: np.ndarray) -> np.ndarray:
        local = np.asarray(t_ns, np.int64) + self.timezone_offset_s * 10**9
        return (local + 500_000) // 1_000_000  # nearest ms

    def _open(self, first_time_ns: Optional[int]) -> BinaryIO:
        t = self.start_time if self.start_time is not None else first_time_ns
        start_text = format_time_ms(int(self._local_ms(np.array([t]))[0])) if t is not None \
            else "0000-00-00 00:00:00:000"
        layout = _header_layout(self, start_text)
        eol = self.eol
        out = bytearray()
        npages_pos = None
        for section, kvs in layout:
            out += section.encode() + eol
            for key, default in kvs:
                value = str(self.header_fields.get(key, default))
                if key == "Number of Pages":
                    npages_pos = len(out) + len(key) + 1
                    value = value.ljust(_NPAGES_WIDTH)
                out += f"{key}:{value}".encode("latin-1") + eol
            out += eol
        f = self._f = open(self._plain, "wb")
        f.write(bytes(out))
        self._npages_pos = npages_pos
        return f

    def _flush(self, final: bool) -> None:
        if not self._pending:
            return
        cols = [np.concatenate([p[i] for p in self._pending]) for i in range(6)]
        t, a, light, btn, temp, batt = cols
        n = t.shape[0]
        whole = (n // GNA_SAMPLES_PER_PAGE) * GNA_SAMPLES_PER_PAGE
        upto = n if (final and self.partial_page == "write") else whole
        if self._f is None:
            self._open(int(t[0]))
        if upto:
            self._write_pages(t[:upto], a[:upto], light[:upto], btn[:upto], temp[:upto], batt[:upto])
        if final or upto == n:
            self._pending, self._pending_n = [], 0
        else:
            self._pending = [tuple(c[upto:] for c in cols)]
            self._pending_n = n - upto

    def _write_pages(self, t, a, light, btn, temp, batt) -> None:
        n = t.shape[0]
        hexm = encode_hex_samples(a, light, btn)  # (n, 12)
        firsts = np.arange(0, n, GNA_SAMPLES_PER_PAGE)
        page_ms = self._local_ms(t[firsts])
        freq_text = _rate_texts(self.rate_hz)[1]
        eol = self.eol
        parts = []
        for j, s in enumerate(firsts):
            e = min(s + GNA_SAMPLES_PER_PAGE, n)
            head = (f"Recorded Data\nDevice Unique Serial Code:{self.serial}\n"
                    f"Sequence Number:{self.pages_written}\n"
                    f"Page Time:{format_time_ms(int(page_ms[j]))}\nUnassigned:\n"
                    f"Temperature:{temp[s]:.1f}\nBattery voltage:{batt[s]:.4f}\n"
                    f"Device Status:Recording\nMeasurement Frequency:{freq_text}\n")
            parts.append(head.replace("\n", eol.decode()).encode())
            parts.append(hexm[s:e].tobytes() + eol)
            self.pages_written += 1
        assert self._f is not None  # opened by _flush before the first page
        self._f.write(b"".join(parts))
        self.samples_written += n
