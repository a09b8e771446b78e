"""Fuzz the readers: mutated .cwa, .bin, gzip, MCAP and ActiGraph .gt3x inputs, each read the way the commands read
them, counted by outcome; and the text a user hands over (sleep logs, cohort manifests, station
profiles) and the requests a network peer sends the dashboard (``http``: an answer that is a 500,
or an error page naming the output folder, counts as ``untyped``).

    python -m tools.fuzz                          # 100,000 inputs per format (cwa, bin, gz, mcap)
    python -m tools.fuzz --count 2000 --formats cwa,mcap --seed 7
    python -m tools.fuzz --save-dir fuzz-out      # keep every input that broke a reader or warned

Outcomes: ``ok`` (read to the end), ``typed`` (a ``StillpointError``: one clear line, exit 2 in the
CLI), ``untyped`` (any other exception: a bug), ``hang`` (over ``--timeout`` s, counted as a bug),
``mismatch`` (a .bin read one page per batch differs from the default read: a bug).
``ok`` inputs that raised a Python warning are also counted under ``warning``. The goal is 0
untyped, 0 hang and 0 mismatch. Deterministic: the same seed gives the same inputs.

Inputs are small seeds (written by the project's own writers, plus the damaged files of
tests/data/fuzz) with one to a few mutations: bit flips, interesting bytes and integers, cuts,
deleted / duplicated / inserted spans, splices of two seeds; structure-aware variants fix the
.cwa sector checksum after a change (so the decoder, not the checksum test, sees it), replace a
GENEActiv ``key:value`` with a hostile value, or mutate one MCAP message / metadata value, put
the raw messages out of order or give a settings value the wrong type or one at or beyond its
bounds (engine.settings.BOUNDS), and rewrite the file with
valid CRCs (so the decoders, not the CRC test, see it). Each .bin is also read one page per batch
(the result must not change), each readable MCAP is also replayed. The in-process smoke test
(tests/tools/test_fuzz_smoke.py) runs a few thousand of these per format in CI.
"""

from __future__ import annotations

import argparse
import collections
import gzip
import io
import os
import signal
import sys
import tempfile
import time
import traceback
import warnings
from pathlib import Path
from typing import Callable, Optional

import numpy as np

FORMATS = ("cwa", "bin", "gz", "mcap", "gt3x", "sleeplog", "manifest", "profile", "http")
FUZZ_DATA = Path(__file__).resolve().parent.parent / "tests" / "data" / "fuzz"
T0 = 1_700_000_000_000_000_000

INTERESTING_INTS = (0, 1, -1, 0x7F, 0x80, 0xFF, 0x7FFF, -0x8000, 0xFFFF, 0x7FFFFFFF, -0x80000000,
                    0xFFFFFFFF, 2**63 - 1, -(2**63))
HOSTILE_VALUES = (b"", b"0", b"-1", b"nan", b"inf", b"-inf", b"1e999", b"1e-308", b"1e308",
                  b"99999999999999999999", b"0.001", b"\xff\xfe", "\u2713".encode(), b"abc",
                  b"2300-01-01 00:00:00:000", b"1600-01-01 00:00:00:000", b"0000-00-00 00:00:00:000",
                  b"1,5", b" ", b"\x00" * 8)


class Hang(Exception):
    pass


class Mismatch(Exception):
    """A reader gave another result at another batch size (a bug, as an untyped error is)."""


# ----------------------------------------------------------------------------- seeds
def _cwa_seed(kind: str, n_sectors: int = 8, rate: float = 100.0) -> bytes:
    from stillpoint.drivers.cwa_writer import CwaWriter
    rng = np.random.default_rng(len(kind))
    kw = {"packed": dict(packed=True), "unpacked": dict(packed=False),
          "ax6": dict(device_type="AX6", gyro_range_dps=500),
          "ax6_accel": dict(device_type="AX6")}[kind]
    per = 120 if kind != "ax6" else 40
    n = per * n_sectors
    t = T0 + np.rint(np.arange(n) * 1e9 / rate).astype(np.int64)
    a = rng.integers(-511, 512, (n, 3)) * 4
    buf = io.BytesIO()
    w = CwaWriter(buf, rate_hz=rate, **kw)
    if kind == "ax6":
        w.write(t, a, gyro_counts=rng.integers(-2000, 2000, (n, 3)))
    else:
        w.write(t, a)
    w.close()
    return buf.getvalue()


def _bin_seed(pages: int = 3, rate: float = 50.0) -> bytes:
    from stillpoint.drivers.geneactiv_writer import GeneactivWriter
    rng = np.random.default_rng(3)
    n = pages * 300
    t = T0 + np.round(np.arange(n) * 1e9 / rate).astype(np.int64)
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "s.bin"
        w = GeneactivWriter(p, rate_hz=rate)
        w.write(t, rng.integers(-2048, 2048, (n, 3)))
        w.close()
        return p.read_bytes()


def _gt3x_seed(kind: str, seconds: int = 40, rate: int = 30) -> bytes:
    """A small .gt3x: ``log`` (log.bin with idle sleep, stored), ``deflated`` (the same, deflated)
    or ``legacy`` (activity.bin, lux.bin and info.txt of the NHANES-era layout)."""
    import zipfile
    from stillpoint.drivers.gt3x_writer import Gt3xWriter, pack12
    rng = np.random.default_rng(11)
    n = seconds * rate
    c = np.zeros((n, 3), np.int64) + [0, 0, 256]
    c[: n // 3] += rng.integers(-40, 40, (n // 3, 3))  # moving, then still (the device sleeps)
    t = T0 + np.arange(n) * 10**9 // rate
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "s.gt3x"
        if kind == "legacy":
            with zipfile.ZipFile(p, "w", zipfile.ZIP_DEFLATED) as z:
                z.writestr("activity.bin", pack12(c[None, :, :])[0].tobytes())
                z.writestr("lux.bin", np.full(seconds, 300, "<u2").tobytes())
                z.writestr("info.txt", "Serial Number: NEO1C00000001\r\nFirmware: 2.5.0\r\n"
                                       f"Sample Rate: {rate}\r\nStart Date: 638000000000000000\r\n"
                                       "TimeZone: -05:00:00\r\n")
            return p.read_bytes()
        w = Gt3xWriter(p, rate_hz=rate, timezone_s=-18000)
        w.write(t, c)
        w.close()
        if kind == "deflated":
            q = Path(d) / "d.gt3x"
            with zipfile.ZipFile(p) as zin, zipfile.ZipFile(q, "w", zipfile.ZIP_DEFLATED) as zout:
                for name in zin.namelist():
                    zout.writestr(name, zin.read(name))
            return q.read_bytes()
        return p.read_bytes()


def _mcap_seed(cwa: bytes, compression: str) -> bytes:
    from stillpoint.engine.run import RunSettings, process_file
    with tempfile.TemporaryDirectory() as d:
        src, out = Path(d) / "s.cwa", Path(d) / "s.mcap"
        src.write_bytes(cwa)
        process_file(src, out, RunSettings(compression=compression, epoch_s=1.0))
        return out.read_bytes()


def build_seeds() -> dict:
    """Small seed inputs per format (bytes)."""
    cwa = [_cwa_seed("packed"), _cwa_seed("unpacked"), _cwa_seed("ax6"), _cwa_seed("ax6_accel"),
           _cwa_seed("packed", 6, 3200.0)]
    for name in ("ax6_mixed_0x62_0x32_sector.cwa", "ax3_3200hz_anchor_back_52ms.cwa"):
        if (FUZZ_DATA / name).exists():
            cwa.append((FUZZ_DATA / name).read_bytes()[:1024 + 12 * 512])
    bins = [_bin_seed(), _bin_seed(2, 85.7)]
    for name in ("geneactiv_temperature_inf.bin", "geneactiv_page_freq_tiny.bin"):
        if (FUZZ_DATA / name).exists():
            bins.append((FUZZ_DATA / name).read_bytes())
    gz = [gzip.compress(cwa[0], mtime=0), gzip.compress(bins[0], mtime=0),
          gzip.compress(cwa[2], mtime=0)]
    long_cwa = _cwa_seed("ax6", 30, 25.0)
    mcap = [_mcap_seed(long_cwa, "none"), _mcap_seed(_cwa_seed("packed", 30, 25.0), "zstd"),
            _mcap_seed(_cwa_seed("unpacked", 30, 25.0), "lz4")]
    gt3x = [_gt3x_seed("log"), _gt3x_seed("deflated"), _gt3x_seed("legacy"),
            _gt3x_seed("log", 130, 60)]
    return {"cwa": cwa, "bin": bins, "gz": gz, "mcap": mcap, "gt3x": gt3x, **_text_seeds()}


# ----------------------------------------------------------------------------- mutators
def _flip(b: bytearray, r) -> None:
    for _ in range(int(r.integers(1, 9))):
        i = int(r.integers(0, len(b)))
        b[i] ^= 1 << int(r.integers(0, 8))


def _byte(b: bytearray, r) -> None:
    for _ in range(int(r.integers(1, 4))):
        b[int(r.integers(0, len(b)))] = int(r.choice([0, 0xFF, 0x7F, 0x80, 0x20, 0x0A]))


def _int(b: bytearray, r) -> None:
    size = int(r.choice([1, 2, 4, 8]))
    if len(b) <= size:
        return
    v = int(r.choice(INTERESTING_INTS))
    i = int(r.integers(0, len(b) - size))
    b[i:i + size] = (v % (1 << (8 * size))).to_bytes(size, "little")


def _cut(b: bytearray, r) -> bytearray:
    return b[:int(r.integers(0, len(b)))]


def _delete(b: bytearray, r) -> bytearray:
    i = int(r.integers(0, len(b)))
    k = int(r.integers(1, max(2, min(4096, len(b) - i))))
    return b[:i] + b[i + k:]


def _dup(b: bytearray, r) -> bytearray:
    i = int(r.integers(0, len(b)))
    k = int(r.integers(1, max(2, min(4096, len(b) - i))))
    j = int(r.integers(0, len(b)))
    return b[:j] + b[i:i + k] + b[j:]


def _insert(b: bytearray, r) -> bytearray:
    j = int(r.integers(0, len(b)))
    return b[:j] + bytearray(r.integers(0, 256, int(r.integers(1, 64)), dtype=np.uint8).tobytes()) + b[j:]


BYTE_MUTATORS = (_flip, _flip, _byte, _int, _int, _cut, _delete, _dup, _insert)


def mutate_bytes(data: bytes, r, others=()) -> bytes:
    b = bytearray(data)
    for _ in range(int(r.integers(1, 4))):
        if not b:
            break
        m = BYTE_MUTATORS[int(r.integers(0, len(BYTE_MUTATORS)))]
        out = m(b, r)
        if out is not None:
            b = out
    if others and r.random() < 0.05:  # splice with another seed
        o = others[int(r.integers(0, len(others)))]
        cut = int(r.integers(0, max(1, min(len(b), len(o)))))
        b = b[:cut] + bytearray(o[cut:])
    return bytes(b)


def _fix_cwa_checksums(data: bytes) -> bytes:
    """Make every whole data sector's checksum valid again (the decoder sees the change)."""
    from stillpoint.drivers.cwa_layout import sector_checksums
    k = (len(data) - 1024) // 512
    if k <= 0:
        return data
    b = np.frombuffer(data, np.uint8).copy()
    sec = b[1024:1024 + k * 512].reshape(k, 512)
    bad = sector_checksums(sec) != 0
    for i in np.flatnonzero(bad):
        w = sec[i].view("<u2")
        w[255] = np.uint16((-int(w[:255].sum(dtype=np.uint16))) & 0xFFFF)
    return b.tobytes()


def mutate_cwa(data: bytes, r, others=()) -> bytes:
    out = mutate_bytes(data, r, others)
    if r.random() < 0.6:
        out = _fix_cwa_checksums(out)
    return out


def mutate_bin(data: bytes, r, others=()) -> bytes:
    if r.random() < 0.5:
        return mutate_bytes(data, r, others)
    lines = data.split(b"\n")
    keyed = [i for i, ln in enumerate(lines) if b":" in ln[:40] and len(ln) < 200]
    for _ in range(int(r.integers(1, 3))):
        if not keyed:
            break
        i = keyed[int(r.integers(0, len(keyed)))]
        key = lines[i].split(b":", 1)[0]
        cr = b"\r" if lines[i].endswith(b"\r") else b""
        lines[i] = key + b":" + HOSTILE_VALUES[int(r.integers(0, len(HOSTILE_VALUES)))] + cr
    if r.random() < 0.3:  # a hostile data line too
        data_lines = [i for i, ln in enumerate(lines) if len(ln) > 1000]
        if data_lines:
            i = data_lines[int(r.integers(0, len(data_lines)))]
            ln = bytearray(lines[i])
            for _ in range(int(r.integers(1, 5))):
                ln[int(r.integers(0, len(ln)))] = int(r.choice(list(b"0F7fG \x00")))
            lines[i] = bytes(ln)
    return b"\n".join(lines)


def mutate_gz(data: bytes, r, others=()) -> bytes:
    if r.random() < 0.3:  # mutate the content, compress again (the reader's checks see it)
        try:
            plain = gzip.decompress(data)
        except Exception:
            return mutate_bytes(data, r, others)
        m = mutate_cwa if plain[:2] == b"MD" else mutate_bin
        return gzip.compress(m(plain, r), mtime=0)
    return mutate_bytes(data, r, others)


def mutate_mcap(data: bytes, r, others=()) -> bytes:
    if r.random() < 0.4:
        return mutate_bytes(data, r, others)
    return _mutate_mcap_messages(data, r)


# JSON values of the wrong type or range for a settings key (a number as text, NaN, ...)
HOSTILE_JSON = ("48", "nan", "", None, True, [], {}, [1], -1, 0, 1e308, -1e308, 2**70, "x" * 70,
                "brotli", 0.5)


def _reorder_raw(msgs: list, r) -> list:
    """Raw messages out of time order: two /raw/accel payloads swapped, all of them reversed, or
    one moved (the log times stay where they were, as a damaged or hand-edited log might hold)."""
    raw = [j for j, (_s, ch, _m) in enumerate(msgs) if ch.topic == "/raw/accel"]
    if len(raw) < 2:
        return [m.data for _s, _c, m in msgs]
    payloads = [m.data for _s, _c, m in msgs]
    kind = int(r.integers(0, 3))
    if kind == 0:
        a, b = r.choice(raw, 2, replace=False).tolist()
        payloads[a], payloads[b] = payloads[b], payloads[a]
    elif kind == 1:
        for j, k in zip(raw, reversed(raw)):
            payloads[j] = msgs[k][2].data
    else:
        a, b = r.choice(raw, 2, replace=False).tolist()
        moved = [payloads[j] for j in raw]
        x = moved.pop(raw.index(a))
        moved.insert(raw.index(b), x)
        for j, p in zip(raw, moved):
            payloads[j] = p
    return payloads


def _settings_value(md: dict, r) -> None:
    """One value of a ``settings`` record replaced by one of the wrong type or range."""
    import json
    try:
        d = json.loads(md.get("json", ""))
    except ValueError:
        return
    if not isinstance(d, dict) or not d:
        return
    if r.random() < 0.5:  # a bounded setting just inside, at or beyond a bound
        from stillpoint.engine.settings import BOUNDS
        k = sorted(BOUNDS)[int(r.integers(0, len(BOUNDS)))]
        lo, hi, _ = BOUNDS[k]
        v = [lo, hi, lo * 0.999, hi * 1.001, lo / 1e9, hi * 1e9, 0][int(r.integers(0, 7))]
        d[k] = int(v) if k == "chunk_size" else v
    else:
        k = list(d)[int(r.integers(0, len(d)))]
        d[k] = HOSTILE_JSON[int(r.integers(0, len(HOSTILE_JSON)))]
    md["json"] = json.dumps(d)


def _mutate_mcap_messages(data: bytes, r) -> bytes:
    """Rewrite the MCAP with valid CRCs after mutating message payloads / metadata values, the
    order of the raw messages, or the type of a settings value."""
    from mcap.reader import make_reader
    from mcap.writer import CompressionType, Writer
    f = io.BytesIO(data)
    reader = make_reader(f)
    msgs = list(reader.iter_messages(log_time_order=False))
    meta = [(m.name, dict(m.metadata)) for m in reader.iter_metadata()]
    kind = r.random()
    payloads = _reorder_raw(msgs, r) if kind < 0.15 else [m.data for _s, _c, m in msgs]
    if 0.15 <= kind < 0.3:
        for name, md in meta:
            if name == "settings":
                _settings_value(md, r)
    out = io.BytesIO()
    w = Writer(out, compression=CompressionType.NONE)
    w.start()
    ids: dict = {}
    targets = set(r.integers(0, max(1, len(msgs)), int(r.integers(1, 4))).tolist()) if kind >= 0.3 else set()
    for j, (sch, ch, m) in enumerate(msgs):
        if ch.id not in ids:
            sid = w.register_schema(sch.name, sch.encoding, sch.data) if sch else 0
            ids[ch.id] = w.register_channel(ch.topic, ch.message_encoding, sid, dict(ch.metadata))
        payload = payloads[j]
        if j in targets:
            payload = mutate_bytes(payload, r) if payload else payload
        w.add_message(ids[ch.id], m.log_time, payload, m.publish_time)
    for name, md in meta:
        if md and kind >= 0.3 and r.random() < 0.3:
            k = list(md)[int(r.integers(0, len(md)))]
            v = md[k].encode()
            md[k] = mutate_bytes(v, r).decode("utf-8", "replace") if v else "x"
        w.add_metadata(name, md)
    w.finish()
    return out.getvalue()


def _fix_gt3x_checksums(log: bytes) -> bytes:
    """Walk the records of a log.bin and make each complete record's checksum valid (the decoder,
    not the checksum test, then sees a change)."""
    b = bytearray(log)
    p = 0
    while p + 8 < len(b):
        if b[p] != 0x1E:
            p += 1
            continue
        end = p + 8 + (b[p + 6] | b[p + 7] << 8)
        if end >= len(b):
            break
        x = 0
        for c in b[p:end]:
            x ^= c
        b[end] = (~x) & 0xFF
        p = end + 1
    return bytes(b)


def mutate_gt3x(data: bytes, r, others=()) -> bytes:
    """Bytes of the zip (a damaged or truncated download), or a member's content re-zipped with
    valid CRCs: log.bin records (sizes, types, times, payloads; checksums made valid again half
    the time), info.txt values, an oversized member (a zip bomb), a cut member."""
    import zipfile
    u = r.random()
    if u < 0.3:
        return mutate_bytes(data, r, others)
    try:
        with zipfile.ZipFile(io.BytesIO(data)) as z:
            members = {zi.filename: (z.read(zi), zi.compress_type) for zi in z.infolist()}
    except Exception:
        return mutate_bytes(data, r, others)
    name = "log.bin" if "log.bin" in members else "activity.bin"
    body, comp = members[name]
    if u < 0.7:
        body = mutate_bytes(body, r)
        if name == "log.bin" and r.random() < 0.5:
            body = _fix_gt3x_checksums(body)
    elif u < 0.85 and "info.txt" in members:
        lines = members["info.txt"][0].split(b"\r\n")
        i = int(r.integers(0, len(lines)))
        key = lines[i].split(b":", 1)[0]
        lines[i] = key + b": " + HOSTILE_VALUES[int(r.integers(0, len(HOSTILE_VALUES)))]
        members["info.txt"] = (b"\r\n".join(lines), members["info.txt"][1])
    elif u < 0.92:
        body = body + b"\0" * int(r.integers(1, 3_000_000))  # zeros between/after records
        comp = zipfile.ZIP_DEFLATED
    else:
        body = body[:int(r.integers(0, max(1, len(body))))]
    members[name] = (body, comp)
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w") as z:
        for n, (b, c) in members.items():
            z.writestr(n, b, compress_type=c)
    return out.getvalue()


# ----------------------------------------------------------------------------- text inputs, requests
# Seeds of the text a user hands over (sleep log, cohort manifest, station profile) and of the
# requests a network peer sends the dashboard, and mutations that push: a cell over csv's field
# limit, nesting thousands deep, a 5,000-character template, a path thousands of levels deep,
# non-ASCII digits, a body over the form limit.
def _text_seeds() -> dict:
    from stillpoint.engine.station.profile import EXAMPLE_PROFILE
    return {
        "sleeplog": [b"ID,onset,wakeup,onset,wakeup\np01,23:00,07:00,22:30,06:45\n",
                     b"ID;D1_date;D1_wakeup;D1_onset\np01;2026-03-28;07:00;23:00\n"],
        "manifest": [b"path,timezone,participant\na.cwa,UTC,P1\nb.bin,Europe/London,\n",
                     b"a.cwa\n# comment\nb.bin\n", b"file,timezone\na.cwa,UTC\n"],
        "profile": [EXAMPLE_PROFILE.encode(), b"[station]\nfile_name = \"{study}_{device}_{session}\"\n"],
        "http": [b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n",
                 b"GET /files/a.txt HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n",
                 b"GET /device/AX3-1/sheet?session=2 HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n",
                 b"POST /action/retry/AX3-1 HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Length: 23\r\n\r\n"
                 b"token=x&confirm=yes&who"],
    }


HOSTILE_TEXT = (lambda r: b"1" * int(r.integers(131_000, 260_000)),  # over csv's field limit
                lambda r: b"\x00\xff\xfe", lambda r: "\u00b2\u0663".encode(), lambda r: b'"',
                lambda r: b"\r", lambda r: b"[" * 5000, lambda r: b"{" * 3000,
                lambda r: b"a" * 5000 + b"{device}_{session}", lambda r: b"%00%2e%2e/",
                lambda r: b"a/" * int(r.integers(100, 4000)), lambda r: b"AX3-\xc2\xb2")


def mutate_text(data: bytes, r, others=()) -> bytes:
    """Byte mutations, or a hostile piece put in place of a field (between separators)."""
    if r.random() < 0.5:
        return mutate_bytes(data, r, others)
    import re
    piece = HOSTILE_TEXT[int(r.integers(0, len(HOSTILE_TEXT)))](r)
    fields = [m.span() for m in re.finditer(rb"[^,;\n\r= /?&]+", data)]
    if not fields:
        return data + piece
    a, b = fields[int(r.integers(0, len(fields)))]
    return data[:a] + piece + data[b:]


def mutate_profile(data: bytes, r, others=()) -> bytes:
    k = r.random()
    if k < 0.15:  # tables or arrays nested deep
        n = int(r.integers(100, 6000))
        return b"x = " + b"[" * n + b"]" * n + b"\n" if r.random() < 0.5 else \
            b"[" + b".".join([b"a"] * n) + b"]\n"
    if k < 0.25:
        return b'[station]\nfile_name = "' + b"a" * int(r.integers(100, 6000)) + b'{device}_{session}"\n'
    return mutate_text(data, r, others)


def mutate_http(data: bytes, r, others=()) -> bytes:
    k = r.random()
    if k < 0.1:  # a body over the form limit, with a request hidden in it
        body = b"x" * int(r.integers(4000, 9000)) + b"GET / HTTP/1.1\r\n\r\n"
        return (b"POST /action/retry/AX3-1 HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Length: "
                + str(len(body)).encode() + b"\r\n\r\n" + body)
    if k < 0.2:
        return b"GET /files/" + b"a/" * int(r.integers(100, 3500)) + b"x HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n"
    return mutate_text(data, r, others)


MUTATORS = {"cwa": mutate_cwa, "bin": mutate_bin, "gz": mutate_gz, "mcap": mutate_mcap,
            "gt3x": mutate_gt3x, "sleeplog": mutate_text, "manifest": mutate_text,
            "profile": mutate_profile, "http": mutate_http}
SUFFIX = {"cwa": ".cwa", "bin": ".bin", "gz": ".gz", "mcap": ".mcap", "gt3x": ".gt3x",
          "sleeplog": ".csv", "manifest": ".csv", "profile": ".toml", "http": ".http"}


# ----------------------------------------------------------------------------- reading
def read_recording(path: Path) -> None:
    """What ``inspect``/``export`` do with a recording: a full pass over every Block, each turned
    into export's per-sample columns (g, dps, degC, lux with the header's light calibration)."""
    from stillpoint.engine.recordings import open_recording
    from stillpoint.engine.export import block_columns
    with open_recording(path) as src:
        for b in src:
            block_columns(b, src.info)
        src.qc.as_dict()


def read_mcap(path: Path) -> None:
    """Every MCAP read path: replay source, export decoding of every topic, recover's walk, and
    (when the raw stream reads) the replay itself: the engine run on the logged stream with the
    logged settings, as ``stillpoint replay`` does."""
    from stillpoint.engine.mcap.replay import McapRawSource
    from stillpoint.engine.mcap.export import _rows
    from stillpoint.engine.mcap.reading import walk_records
    from stillpoint.engine.mcap.stream import iter_messages
    try:
        with McapRawSource(path) as src:
            for b in src:
                b.accel_g()
                b.unit_of_sample()
            logged = dict(src.settings or {})
            src.logged_calibration()  # as tables from a log read it
    finally:
        with open(path, "rb") as f:
            for _ in walk_records(f):
                pass
    for topic, i, msg in iter_messages(path):
        if topic in ("/corrected/accel", "/raw/accel", "/raw/gyro", "/metrics/epoch", "/temperature",
                     "/calibration", "/qc"):
            _rows(topic, msg.data, msg.log_time, path, i)
    from stillpoint.engine.run import RunSettings, process_file
    logged.setdefault("view_hz", 0.0)  # as tools/cli/commands/replay.py
    out = path.with_name(path.stem + ".replay.mcap")
    try:
        process_file(path, out, RunSettings.from_dict(logged))
    finally:
        for p in path.parent.glob(path.stem + ".replay*"):
            p.unlink()


def _whole_read(path: Path, **opts):
    """(digest of every sample's time, counts and segment, QC counts and events) of a read, or
    the typed error it raised."""
    import hashlib
    from stillpoint.engine.recordings import open_recording
    from stillpoint.engine.core.errors import StillpointError
    from stillpoint.engine.export import block_columns
    h = [hashlib.sha256() for _ in range(3)]  # one per field: block boundaries do not matter
    try:
        with open_recording(path, **opts) as src:
            for b in src:
                block_columns(b, src.info)
                for hf, a in zip(h, (b.time_ns, b.accel, np.full(b.n, b.segment, np.int64))):
                    hf.update(np.ascontiguousarray(a).tobytes())
        q = src.qc
        return ([hf.hexdigest() for hf in h], (q.total, q.valid, q.skipped, q.segments),
                [(e.index, e.reason, e.detail) for e in q.events])
    except StillpointError as e:
        return e


def read_bin_every_batch(path: Path) -> None:
    """A .bin read as ``read_recording`` does, and again one page per batch: the two must agree
    (samples, times, segments, QC), or both raise the same typed error."""
    ref, one = _whole_read(path), _whole_read(path, batch_pages=1)
    same = (type(ref) is type(one)) if isinstance(ref, Exception) else (ref == one)
    if not same:
        what = lambda r: type(r).__name__ if isinstance(r, Exception) else f"{r[1]}"  # noqa: E731
        raise Mismatch(f"batch_pages=1 gives {what(one)}, the default {what(ref)}")
    if isinstance(ref, Exception):
        raise ref


def read_gt3x(path: Path) -> None:
    """A .gt3x read as ``read_recording`` does and again in 7-second blocks (the two must agree),
    then written as ActiLife's CSV (``export --actilife``) to memory."""
    from stillpoint.drivers.actilife_csv import write_actilife_csv
    from stillpoint.drivers.gt3x import Gt3xReader
    ref, small = _whole_read(path), _whole_read(path, batch_seconds=7)
    same = (type(ref) is type(small)) if isinstance(ref, Exception) else (ref == small)
    if not same:
        what = lambda r: type(r).__name__ if isinstance(r, Exception) else f"{r[1]}"  # noqa: E731
        raise Mismatch(f"batch_seconds=7 gives {what(small)}, the default {what(ref)}")
    if isinstance(ref, Exception):
        raise ref
    with Gt3xReader(path) as src:
        write_actilife_csv(src, _Discard())


class _Discard:
    """A text sink that keeps nothing (the CSV's rows are formatted, not stored)."""

    def write(self, text: str) -> int:
        return len(text)


def read_sleeplog(path: Path) -> None:
    from stillpoint.engine.sleep.diary import read_sleep_log
    read_sleep_log(path, "p01")


def read_manifest(path: Path) -> None:
    from stillpoint.engine.cohort import discover_inputs
    discover_inputs([path], {})


def read_profile(path: Path) -> None:
    from stillpoint.engine.station.profile import load_profile
    load_profile(path)


class ServerBug(Exception):
    """The dashboard answered 500, named its folder, or did not close a refused connection."""


_DASH: dict = {}


def send_request(path: Path) -> None:
    """The input as one request to a dashboard on loopback (started once, serving a folder with
    one file); the answer must not be a 500, and no error page may name the folder."""
    import socket
    if "dash" not in _DASH:
        from stillpoint.engine.station.web import Dashboard
        folder = Path(tempfile.mkdtemp(prefix="stillpoint-fuzz-dash-"))
        (folder / "a.txt").write_text("hello")
        d = Dashboard(folder)
        d.start()
        _DASH.update(dash=d, folder=str(folder).encode())
    d = _DASH["dash"]
    with socket.create_connection(("127.0.0.1", d.httpd.server_address[1]), timeout=15) as s:
        try:
            s.sendall(path.read_bytes())
            s.shutdown(socket.SHUT_WR)
            answer = b""
            while len(answer) < 1 << 20:
                part = s.recv(65536)
                if not part:
                    break
                answer += part
        except ConnectionResetError:  # refused before all of it was read
            return
        except socket.timeout:
            raise ServerBug("no answer and no close in 15 s") from None
    status = answer.split(b"\r\n", 1)[0]
    refused = status[9:10] in (b"4", b"5")  # an error page (the dock itself shows its folder)
    if b" 500 " in status or (refused and _DASH["folder"] in answer):
        raise ServerBug(status.decode("latin-1")[:80])


READERS = {"cwa": read_recording, "bin": read_bin_every_batch, "gz": read_recording,
           "mcap": read_mcap, "gt3x": read_gt3x, "sleeplog": read_sleeplog,
           "manifest": read_manifest, "profile": read_profile, "http": send_request}


def classify(fmt: str, path: Path, timeout_s: float) -> tuple[str, str]:
    """(outcome, detail) of reading one input."""
    from stillpoint.engine.core.errors import StillpointError
    use_alarm = timeout_s > 0 and hasattr(signal, "SIGALRM")
    if use_alarm:
        signal.setitimer(signal.ITIMER_REAL, timeout_s)
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            with np.errstate(all="warn"):
                READERS[fmt](path)
        if caught:
            w = caught[0]
            return "warning", f"{w.category.__name__} {Path(w.filename).name}:{w.lineno}: {w.message}"
        return "ok", ""
    except StillpointError:
        return "typed", ""
    except Hang:
        return "hang", f"over {timeout_s} s"
    except Mismatch as e:
        return "mismatch", str(e)
    except ServerBug as e:
        return "untyped", f"dashboard: {e}"
    except Exception as e:
        tb = traceback.extract_tb(e.__traceback__)
        where = next((f"{Path(fr.filename).name}:{fr.lineno}" for fr in reversed(tb)
                      if "stillpoint" in fr.filename or "/wt/" in fr.filename or "drivers" in fr.filename
                      or "engine" in fr.filename), f"{Path(tb[-1].filename).name}:{tb[-1].lineno}" if tb else "?")
        return "untyped", f"{type(e).__name__} at {where}: {str(e)[:120]}"
    finally:
        if use_alarm:
            signal.setitimer(signal.ITIMER_REAL, 0)


def _on_alarm(signum, frame):
    raise Hang()


def run(formats=FORMATS, count: int = 100_000, seed: int = 0, timeout_s: float = 10.0,
        save_dir: Optional[Path] = None, seeds: Optional[dict] = None,
        progress: Optional[Callable[[str, int, collections.Counter], None]] = None,
        time_budget_s: Optional[float] = None) -> dict:
    """Fuzz ``count`` inputs per format; returns {format: {"counts": Counter, "kinds": Counter,
    "inputs": n}}. ``time_budget_s`` (per format) stops a format early (the count run is reported)."""
    seeds = seeds or build_seeds()
    old = signal.signal(signal.SIGALRM, _on_alarm) if hasattr(signal, "SIGALRM") else None
    tmp = Path(tempfile.mkdtemp(prefix="stillpoint-fuzz-", dir="/dev/shm" if os.path.isdir("/dev/shm") else None))
    results = {}
    try:
        for fi, fmt in enumerate(formats):
            r = np.random.default_rng([seed, fi])
            counts: collections.Counter = collections.Counter()
            kinds: collections.Counter = collections.Counter()
            pool = seeds[fmt]
            path = tmp / f"input{SUFFIX[fmt]}"
            t0 = time.monotonic()
            n = 0
            for n in range(1, count + 1):
                data = MUTATORS[fmt](pool[int(r.integers(0, len(pool)))], r, pool)
                path.write_bytes(data)
                outcome, detail = classify(fmt, path, timeout_s)
                counts[outcome] += 1
                if outcome in ("untyped", "hang", "warning", "mismatch"):
                    kinds[detail[:160]] += 1
                    if save_dir is not None:
                        save_dir.mkdir(parents=True, exist_ok=True)
                        (save_dir / f"{fmt}-{seed}-{n}-{outcome}{SUFFIX[fmt]}").write_bytes(data)
                if progress is not None and n % 1000 == 0:
                    progress(fmt, n, counts)
                if time_budget_s is not None and time.monotonic() - t0 > time_budget_s:
                    break
            results[fmt] = {"counts": counts, "kinds": kinds, "inputs": n,
                            "seconds": time.monotonic() - t0}
    finally:
        if old is not None:
            signal.signal(signal.SIGALRM, old)
        for p in tmp.iterdir():
            p.unlink()
        tmp.rmdir()
    return results


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--count", type=int, default=100_000, help="inputs per format (default 100,000)")
    ap.add_argument("--formats", default=",".join(FORMATS), help="comma list of " + ", ".join(FORMATS))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--timeout", type=float, default=10.0, help="seconds per input before it is a hang")
    ap.add_argument("--save-dir", type=Path,
                    help="keep every input with an untyped error, hang, mismatch or warning here")
    ap.add_argument("--memory-gb", type=float, default=4.0,
                    help="address-space limit, so a runaway allocation is an error, not a swap storm")
    args = ap.parse_args(argv)
    try:
        import resource
        lim = int(args.memory_gb * (1 << 30))
        resource.setrlimit(resource.RLIMIT_AS, (lim, lim))
    except (ImportError, ValueError, OSError):
        pass
    formats = [f.strip() for f in args.formats.split(",") if f.strip()]
    t0 = time.monotonic()

    def progress(fmt, n, counts):
        if n % 10_000 == 0:
            print(f"  {fmt}: {n:,} inputs, {dict(counts)} ({time.monotonic() - t0:.0f} s)",
                  file=sys.stderr, flush=True)

    res = run(formats, args.count, args.seed, args.timeout, args.save_dir, progress=progress)
    total_bad = 0
    print(f"fuzz: seed {args.seed}, {args.count:,} inputs per format, {time.monotonic() - t0:.0f} s")
    print(f"{'format':<6} {'inputs':>8} {'ok':>8} {'warning':>8} {'typed':>8} {'untyped':>8} {'hang':>6}"
          f" {'mismatch':>8}")
    for fmt, d in res.items():
        c = d["counts"]
        print(f"{fmt:<6} {d['inputs']:>8,} {c['ok']:>8,} {c['warning']:>8,} {c['typed']:>8,} "
              f"{c['untyped']:>8,} {c['hang']:>6,} {c['mismatch']:>8,}")
        total_bad += c["untyped"] + c["hang"] + c["mismatch"]
    for fmt, d in res.items():
        for kind, k in d["kinds"].most_common(20):
            print(f"  {fmt} x{k}: {kind}")
    return 1 if total_bad else 0


if __name__ == "__main__":
    sys.exit(main())
