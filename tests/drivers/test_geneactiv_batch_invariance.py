"""A damaged GENEActiv file reads the same at every ``batch_pages`` and in follow mode (the file
growing in arbitrary pieces while it is read): same samples, times, segments and QC log. Page
fields are judged on their own, never against the pages that happen to share a read batch."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from stillpoint.engine.core.errors import StillpointError
from stillpoint.drivers.geneactiv import GeneactivReader, GeneactivWriter
from stillpoint.drivers.geneactiv_header import parse_time_ms, parse_times_ms

PAGES = 6
# values a damaged or foreign file may hold in a page's key:value line
HOSTILE = (b"", b"0", b"-1", b"nan", b"inf", b"1e308", b"12,5,5", b"1,5", b"abc", b" ",
           b"2013-05-30T10:12:54:500", b"2013-05-30 10:12:54.500", b"2013-5-30 10:12:54:500",
           b"2020-01-01 00:00:00:000", b"0000-00-00 00:00:00:000", b"2300-01-01 00:00:00:000",
           b"garbage", b"99999999999999999999")


def _small_bin(path, rate: float) -> None:
    n = PAGES * 300
    rng = np.random.default_rng(3)
    t = 1_600_000_000_000_000_000 + np.round(np.arange(n) * 1e9 / rate).astype(np.int64)
    w = GeneactivWriter(path, rate_hz=rate)
    w.write(t, rng.integers(-2048, 2048, (n, 3)))
    w.close()


def _damage(data: bytes, rng, n: int) -> bytes:
    """``n`` random kinds of damage after the header: bit flips, a page value replaced by a hostile
    one, a line deleted or repeated, the end cut off."""
    start = data.find(b"Recorded Data")
    head, body = data[:start], bytearray(data[start:])
    for _ in range(n):
        kind = int(rng.integers(0, 5))
        lines = body.split(b"\n")
        if kind == 0:
            for _ in range(int(rng.integers(1, 4))):
                i = int(rng.integers(0, len(body)))
                body[i] ^= 1 << int(rng.integers(0, 8))
            continue
        if kind == 1:
            keyed = [i for i, ln in enumerate(lines) if b":" in ln[:40] and len(ln) < 200]
            i = keyed[int(rng.integers(0, len(keyed)))]
            cr = b"\r" if lines[i].endswith(b"\r") else b""
            lines[i] = lines[i].split(b":", 1)[0] + b":" + HOSTILE[int(rng.integers(0, len(HOSTILE)))] + cr
        elif kind == 2 and len(lines) > 2:
            del lines[int(rng.integers(0, len(lines)))]
        elif kind == 3:
            i = int(rng.integers(0, len(lines)))
            lines.insert(i, lines[i])
        elif kind == 4:
            body = body[:int(rng.integers(len(body) // 2, len(body) + 1))]
            continue
        body = bytearray(b"\n".join(lines))
    return bytes(head + body)


def snapshot(reader) -> tuple:
    """Samples, times, segments, per-page fields and the QC log of a whole read; or the typed
    error's class when the file is refused."""
    try:
        with reader as src:
            blocks = list(src)
    except StillpointError as e:
        return ("refused", type(e).__name__)
    cat = np.concatenate
    arrays = {}
    if blocks:
        for f in ("time_ns", "accel", "unit_index", "unit_sequence", "temperature_c", "battery_v",
                  "light"):
            arrays[f] = cat([getattr(b, f) for b in blocks])
        arrays["segment"] = cat([np.full(b.n, b.segment) for b in blocks])
        arrays["light_raw"] = cat([b.per_sample["light_raw"] for b in blocks])
    qc = reader.qc
    events = [(e.index, e.reason, e.detail, e.time_ns, e.samples) for e in qc.events]
    return ("read", (qc.total, qc.valid, qc.skipped, qc.segments), events,
            {k: [None if x != x else x for x in v.tolist()] for k, v in arrays.items()})  # NaN == NaN


class _Growing:
    """A file written in pieces while it is followed: each time the reader finds no new bytes the
    next piece is appended (deterministic, no waiting); done once every piece is written."""

    def __init__(self, path, data: bytes, cuts: list[int]):
        self.path, self.data = path, data
        edges = sorted({c for c in cuts if 0 < c < len(data)} | {len(data)})
        self.pieces = [data[a:b] for a, b in zip([0] + edges[:-1], edges)]
        path.write_bytes(self.pieces.pop(0))

    def done(self) -> bool:
        if self.pieces:
            with open(self.path, "ab") as f:
                f.write(self.pieces.pop(0))
        return True


def _check_invariant(path, data: bytes, rng) -> tuple:
    path.write_bytes(data)
    ref = snapshot(GeneactivReader(path))
    for batch in range(1, PAGES + 2):
        assert snapshot(GeneactivReader(path, batch_pages=batch)) == ref, f"batch_pages={batch}"
    if data:
        for batch in (1, 2, 256):
            cuts = sorted(rng.integers(1, max(2, len(data)), int(rng.integers(1, 12))).tolist())
            g = _Growing(path, data, cuts)
            got = snapshot(GeneactivReader(path, batch_pages=batch, follow=True, follow_done=g.done,
                                           follow_idle_s=0))
            assert got == ref, f"follow mode, batch_pages={batch}, pieces cut at {cuts}"
    return ref


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**32 - 1), damage=st.integers(0, 6), rate=st.sampled_from([50.0, 85.7, 100.0]))
@example(seed=0, damage=0, rate=85.7)
def test_damaged_bin_reads_the_same_at_every_batch_size_and_in_follow_mode(tmp_path, seed, damage, rate):
    clean = tmp_path / "clean.bin"
    _small_bin(clean, rate)
    rng = np.random.default_rng(seed)
    data = _damage(clean.read_bytes(), rng, damage)
    ref = _check_invariant(tmp_path / "damaged.bin", data, rng)
    if damage == 0:
        assert ref[0] == "read" and ref[1] == (PAGES, PAGES, 0, 1) and ref[2] == []


def test_a_page_time_no_device_writes_is_judged_on_its_own(tmp_path):
    """'2013-05-30T10:12:54:500' has the fixed width, so it used to be refused by the vectorised
    parse when its batch held only fixed-width times, and read by the per-value parse otherwise."""
    clean = tmp_path / "clean.bin"
    _small_bin(clean, 85.7)
    lines = clean.read_bytes().split(b"\n")
    times = [i for i, ln in enumerate(lines) if ln.startswith(b"Page Time:")]
    odd = b"Page Time:" + lines[times[3]][len(b"Page Time:"):].replace(b" ", b"T", 1)
    assert len(odd.strip()) == len(lines[times[3]].strip()) and b"-13T12" in odd
    lines[times[1]] = b"Page Time:garbage\r"  # another width, in another page
    lines[times[3]] = odd
    data = b"\n".join(lines)
    ref = _check_invariant(tmp_path / "odd.bin", data, np.random.default_rng(0))
    assert ref[0] == "read" and ref[1][:3] == (PAGES, PAGES - 1, 1)  # only 'garbage' skipped


@pytest.mark.parametrize("values", [
    [b"2013-05-30 10:12:54:500", b"2013-05-30T10:12:54:500", b"2013-05-30 10:12:54.500",
     b"2013-5-30 10:12:54:500", b"garbage", b"0000-00-00 00:00:00:000", b"2013-02-29 00:00:00:000"],
])
def test_times_parse_alone_as_in_a_list(values):
    t, ok = parse_times_ms(values)
    for v, ti, oki in zip(values, t.tolist(), ok.tolist()):
        alone = parse_time_ms(v.decode("latin-1"))
        assert (alone is not None) == oki, v
        if oki:
            assert ti == alone, v
    for v in values:  # a list of one
        t1, ok1 = parse_times_ms([v])
        assert ok1[0] == ok[values.index(v)] and (not ok1[0] or t1[0] == t[values.index(v)])
