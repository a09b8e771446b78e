"""Helpers shared by the .cwa tests: read a whole (small) file into arrays, make synthetic data,
write a damaged file."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from stillpoint.drivers.cwa import CwaReader

T0_NS = 1_700_000_000_123_456_789  # 2023-11-14T22:13:20.123456789Z


def read_all(path, **kw):
    """All blocks of a small file joined: dict of arrays plus the reader (for .info / .qc)."""
    r = CwaReader(path, **kw)
    blocks = list(r)
    out = {"reader": r, "blocks": blocks}
    if not blocks:
        return out
    cat = np.concatenate
    out["time"] = cat([b.time_ns for b in blocks])
    out["accel"] = cat([b.accel for b in blocks])
    out["gyro"] = cat([b.gyro for b in blocks]) if blocks[0].gyro is not None else None
    out["segment"] = cat([np.full(b.n, b.segment) for b in blocks])
    out["unit_index"] = cat([b.unit_index for b in blocks])
    out["unit_sequence"] = cat([b.unit_sequence for b in blocks])
    out["temperature_raw"] = cat([b.temperature_raw for b in blocks])
    out["temperature_c"] = cat([b.temperature_c for b in blocks])
    out["battery_v"] = cat([b.battery_v for b in blocks])
    out["light"] = cat([b.light for b in blocks])
    out["events"] = cat([b.events for b in blocks])
    out["first_sample"] = [b.first_sample for b in blocks]
    out["n"] = sum(b.n for b in blocks)
    return out


def synth(n, *, rate=100.0, drift=0.991, start_ns=T0_NS, seed=0, multiple=4, limit=511):
    """Per-sample times at ``rate*drift`` Hz and representable packed counts (multiples)."""
    rng = np.random.default_rng(seed)
    period = 1e9 / (rate * drift)
    t = start_ns + np.rint(np.arange(n) * period).astype(np.int64)
    a = rng.integers(-limit - 1, limit + 1, (n, 3)) * multiple
    return t, a


def qc_reasons(reader):
    return [(e.index, e.reason) for e in reader.qc.events]


def damaged_cwa(path, seed: int):
    """A packed 100 Hz .cwa of 400 sectors with 25 single-bit flips in sector checksums and
    headers (a seeded choice): readers log each as QC and go on."""
    from stillpoint.drivers.cwa_writer import CwaWriter
    rng = np.random.default_rng(seed)
    n = 120 * 400
    t = 1_700_000_000_000_000_000 + np.rint(np.arange(n) * 1e7).astype(np.int64)
    a = (np.sin(np.arange(n)[:, None] / 50.0 + np.arange(3)) * 400).astype(np.int64) + rng.integers(-8, 9, (n, 3))
    w = CwaWriter(path, rate_hz=100, packed=True)
    w.write(t, a)
    w.close()
    path = Path(path)
    data = bytearray(path.read_bytes())
    for s in rng.choice(np.arange(2, 390), 25, replace=False):  # checksum / header damage
        i = 1024 + int(s) * 512 + int(rng.integers(0, 512))
        data[i] ^= 1 << int(rng.integers(0, 8))
    path.write_bytes(bytes(data))
    return path
