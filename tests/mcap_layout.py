"""An MCAP layout checker written against the MCAP specification (https://mcap.dev/spec), not
against our writer: it parses every record of a file itself and checks

* magic at both ends, Header first, Footer last; every record's length within the file;
* the data section: each Chunk's CRC32 of its decompressed records, its time range and size;
  the records inside a chunk; each Chunk followed by exactly one Message Index per channel that
  has messages in it, whose entries are (log_time, offset) of every Message of that channel,
  sorted by log time, each offset pointing at a Message record with that channel and log time;
* Data End: the CRC32 of everything before it (magic included) when non-zero;
* the summary: Chunk Index records (one per chunk, offset/length/compression/sizes/time range
  and message-index offsets and length matching the data section), Statistics (message,
  schema, channel, chunk, metadata counts; per-channel counts; time range), Schema and Channel
  copies, Metadata Index records pointing at the Metadata records;
* Summary Offset records covering exactly the summary groups; the Footer's summary start,
  summary offset start and summary CRC.

``check_layout(path)`` raises ``AssertionError`` naming the first violation and returns a
small report (counts) for further assertions.
"""

from __future__ import annotations

import struct
import zlib

MAGIC = b"\x89MCAP0\r\n"
OP = {0x01: "Header", 0x02: "Footer", 0x03: "Schema", 0x04: "Channel", 0x05: "Message",
      0x06: "Chunk", 0x07: "MessageIndex", 0x08: "ChunkIndex", 0x09: "Attachment",
      0x0A: "AttachmentIndex", 0x0B: "Statistics", 0x0C: "Metadata", 0x0D: "MetadataIndex",
      0x0E: "SummaryOffset", 0x0F: "DataEnd"}


class _R:
    """Little-endian field reader over a bytes-like object."""

    def __init__(self, b, pos=0):
        self.b, self.p = b, pos

    def u8(self):
        v = self.b[self.p]
        self.p += 1
        return v

    def u16(self):
        v, = struct.unpack_from("<H", self.b, self.p)
        self.p += 2
        return v

    def u32(self):
        v, = struct.unpack_from("<I", self.b, self.p)
        self.p += 4
        return v

    def u64(self):
        v, = struct.unpack_from("<Q", self.b, self.p)
        self.p += 8
        return v

    def str(self):
        n = self.u32()
        v = bytes(self.b[self.p:self.p + n]).decode("utf-8")
        self.p += n
        return v

    def bytes32(self):
        n = self.u32()
        v = bytes(self.b[self.p:self.p + n])
        self.p += n
        return v

    def bytes64(self):
        n = self.u64()
        v = bytes(self.b[self.p:self.p + n])
        self.p += n
        return v


def _records(buf, start, end):
    """(opcode, body start, body end, record start) of every record in buf[start:end]."""
    p = start
    while p < end:
        assert p + 9 <= end, f"record header torn at {p}"
        op, n = struct.unpack_from("<BQ", buf, p)
        assert p + 9 + n <= end, f"record at {p} (op {op:#x}) runs past its section"
        yield op, p + 9, p + 9 + n, p
        p += 9 + n


def _decompress(compression, data, size):
    if compression == "":
        return data
    if compression == "zstd":
        import zstandard
        return zstandard.ZstdDecompressor().decompress(data, max_output_size=size)
    if compression == "lz4":
        import lz4.frame
        return lz4.frame.decompress(data)
    raise AssertionError(f"unknown compression {compression!r}")


def check_layout(path) -> dict:
    with open(path, "rb") as f:
        buf = f.read()
    assert buf[:8] == MAGIC, "no leading magic"
    assert buf[-8:] == MAGIC, "no trailing magic (unfinished file)"
    # ---- footer
    foot = len(buf) - 8 - 29
    op, n = struct.unpack_from("<BQ", buf, foot)
    assert op == 0x02 and n == 20, "no Footer before the trailing magic"
    summary_start, summary_offset_start, summary_crc = struct.unpack_from("<QQI", buf, foot + 9)
    assert summary_start and summary_offset_start, "no summary / summary offsets"
    assert summary_start <= summary_offset_start <= foot
    # ---- data section
    first = next(_records(buf, 8, len(buf)))
    assert first[0] == 0x01, "first record is not a Header"
    data_end_at = None
    chunks = []  # per chunk: dict
    metadata = []  # (offset, length, name)
    schemas, channels = {}, {}
    counts: dict[int, int] = {}
    t_min, t_max = None, None
    recs = list(_records(buf, 8, summary_start))
    i = 0
    while i < len(recs):
        op, a, b, at = recs[i]
        name = OP.get(op)
        if op == 0x0F:
            data_end_at = at
            crc = struct.unpack_from("<I", buf, a)[0]
            if crc:
                assert crc == zlib.crc32(buf[:at]), "Data End CRC is not the data section's CRC32"
            assert b == summary_start, "records between Data End and the summary"
            i += 1
            break
        assert name is not None, f"unknown opcode {op:#x} at {at}"
        if op == 0x03:
            r = _R(buf, a)
            sid = r.u16()
            schemas[sid] = (r.str(), r.str(), r.bytes32())
        elif op == 0x04:
            r = _R(buf, a)
            cid, sid = r.u16(), r.u16()
            channels[cid] = (sid, r.str(), r.str())
        elif op == 0x0C:
            r = _R(buf, a)
            metadata.append((at, b - at, r.str()))
        elif op == 0x05:
            raise AssertionError(f"a Message outside a chunk at {at}")
        elif op == 0x06:
            r = _R(buf, a)
            cstart, cend, usize, ucrc = r.u64(), r.u64(), r.u64(), r.u32()
            comp = r.str()
            cdata = r.bytes64()
            assert r.p == b, f"Chunk at {at}: fields do not fill the record"
            raw = _decompress(comp, cdata, usize)
            assert len(raw) == usize, f"Chunk at {at}: uncompressed size"
            if ucrc:
                assert zlib.crc32(raw) == ucrc, f"Chunk at {at}: CRC mismatch"
            per_channel: dict[int, list] = {}
            for iop, ia, _ib, iat in _records(raw, 0, len(raw)):
                assert iop in (0x03, 0x04, 0x05), f"Chunk at {at}: record {iop:#x} inside a chunk"
                r2 = _R(raw, ia)
                if iop == 0x05:
                    cid, _seq, lt, _pt = r2.u16(), r2.u32(), r2.u64(), r2.u64()
                    assert cid in channels, f"Chunk at {at}: message on channel {cid} before its Channel"
                    per_channel.setdefault(cid, []).append((lt, iat))
                    assert cstart <= lt <= cend, f"Chunk at {at}: message time outside its range"
                    counts[cid] = counts.get(cid, 0) + 1
                    t_min = lt if t_min is None else min(t_min, lt)
                    t_max = lt if t_max is None else max(t_max, lt)
                elif iop == 0x03:
                    sid = r2.u16()
                    schemas[sid] = (r2.str(), r2.str(), r2.bytes32())
                else:
                    cid, sid = r2.u16(), r2.u16()
                    channels[cid] = (sid, r2.str(), r2.str())
            if per_channel:
                lo = min(t for v in per_channel.values() for t, _ in v)
                hi = max(t for v in per_channel.values() for t, _ in v)
                assert (lo, hi) == (cstart, cend), f"Chunk at {at}: time range is not its messages'"
            # the chunk's Message Index records follow it
            j = i + 1
            idx_offsets, idx_start = {}, recs[j][3] if j < len(recs) else b
            while j < len(recs) and recs[j][0] == 0x07:
                _op, ia, ib, iat = recs[j]
                r3 = _R(buf, ia)
                cid, n = r3.u16(), r3.u32()
                assert n % 16 == 0 and ia + 6 + n == ib, f"Message Index at {iat}: length"
                entries = [struct.unpack_from("<QQ", buf, ia + 6 + 16 * k) for k in range(n // 16)]
                assert cid not in idx_offsets, f"two Message Index records for channel {cid}"
                idx_offsets[cid] = iat
                assert [e[0] for e in entries] == sorted(e[0] for e in entries), \
                    f"Message Index at {iat}: entries not sorted by log time"
                assert sorted(entries, key=lambda e: e[1]) == sorted(per_channel.get(cid, []),
                                                                     key=lambda e: e[1]), \
                    f"Message Index at {iat}: entries are not channel {cid}'s messages"
                for lt, off in entries:
                    assert raw[off] == 0x05, f"Message Index at {iat}: offset {off} is no Message"
                    mcid, _s, mlt = struct.unpack_from("<HIQ", raw, off + 9)
                    assert (mcid, mlt) == (cid, lt), f"Message Index at {iat}: wrong message"
                j += 1
            assert set(idx_offsets) == set(per_channel), \
                f"Chunk at {at}: Message Index records for {sorted(idx_offsets)}, " \
                f"messages on {sorted(per_channel)}"
            idx_end = recs[j - 1][2] if j > i + 1 else idx_start
            chunks.append({"offset": at, "length": b - at, "start": cstart, "end": cend,
                           "compression": comp, "csize": len(cdata), "usize": usize,
                           "index_offsets": idx_offsets,
                           "index_length": (idx_end - idx_start) if idx_offsets else 0})
            i = j
            continue
        elif op == 0x07:
            raise AssertionError(f"a Message Index at {at} that follows no chunk")
        i += 1
    assert data_end_at is not None, "no Data End record"
    # ---- summary section
    groups: dict[int, list] = {}
    for op, a, b, at in _records(buf, summary_start, summary_offset_start):
        assert op not in (0x05, 0x06, 0x07, 0x0F), f"record {op:#x} in the summary"
        groups.setdefault(op, []).append((a, b, at))
    # summary offsets: one per group, covering it exactly
    offs = {}
    for op, a, _b, _at in _records(buf, summary_offset_start, foot):
        assert op == 0x0E, "a non-Summary-Offset record after the summary offset start"
        gop, gstart, glen = struct.unpack_from("<BQQ", buf, a)
        offs[gop] = (gstart, glen)
    for gop, items in groups.items():
        assert gop in offs, f"no Summary Offset for group {gop:#x}"
        gstart, glen = offs[gop]
        assert gstart == items[0][2] and gstart + glen == items[-1][1], \
            f"Summary Offset of group {gop:#x} does not cover it"
    assert set(offs) == set(groups), "Summary Offset for a group that is not there"
    # footer CRC: summary start .. footer's summary_offset_start field
    if summary_crc:
        assert summary_crc == zlib.crc32(buf[summary_start:foot + 9 + 16]), "summary CRC mismatch"
    # chunk indexes
    cis = []
    for a, b, at in groups.get(0x08, []):
        r = _R(buf, a)
        st, en, off, ln = r.u64(), r.u64(), r.u64(), r.u64()
        m = r.u32()
        io = {}
        end_map = r.p + m
        while r.p < end_map:
            c = r.u16()
            io[c] = r.u64()
        il = r.u64()
        comp = r.str()
        cs, us = r.u64(), r.u64()
        assert r.p == b, f"Chunk Index at {at}: fields do not fill the record"
        cis.append({"offset": off, "length": ln, "start": st, "end": en, "compression": comp,
                    "csize": cs, "usize": us, "index_offsets": io, "index_length": il})
    assert len(cis) == len(chunks), f"{len(cis)} Chunk Index records for {len(chunks)} chunks"
    for ci, ch in zip(sorted(cis, key=lambda c: c["offset"]), chunks):
        assert ci == ch, f"Chunk Index {ci} does not match the chunk {ch}"
    # statistics
    st = groups.get(0x0B)
    assert st and len(st) == 1, "no (or several) Statistics record"
    r = _R(buf, st[0][0])
    mc, sc, cc, _ac, mdc, chc, s0, s1 = (r.u64(), r.u16(), r.u32(), r.u32(), r.u32(), r.u32(),
                                        r.u64(), r.u64())
    n = r.u32()
    per = {}
    for _ in range(n // 10):
        c = r.u16()
        per[c] = r.u64()
    assert mc == sum(counts.values()), "Statistics message count"
    assert per == counts, "Statistics per-channel counts"
    assert chc == len(chunks), "Statistics chunk count"
    assert mdc == len(metadata), "Statistics metadata count"
    assert cc == len(channels) and sc == len(schemas), "Statistics schema/channel counts"
    if counts:
        assert (s0, s1) == (t_min, t_max), "Statistics time range"
    # schema / channel copies
    for a, _b, _at in groups.get(0x03, []):
        r = _R(buf, a)
        sid = r.u16()
        assert schemas.get(sid) == (r.str(), r.str(), r.bytes32()), f"summary Schema {sid}"
    for a, _b, _at in groups.get(0x04, []):
        r = _R(buf, a)
        cid, sid = r.u16(), r.u16()
        assert channels.get(cid) == (sid, r.str(), r.str()), f"summary Channel {cid}"
    assert len(groups.get(0x04, [])) == len(channels), "summary lacks Channel records"
    # metadata indexes
    mis = []
    for a, _b, _at in groups.get(0x0D, []):
        r = _R(buf, a)
        mis.append((r.u64(), r.u64(), r.str()))
    assert sorted(mis) == sorted(metadata), "Metadata Index records do not match the Metadata"
    for cid, (sid, _topic, _enc) in channels.items():
        assert sid == 0 or sid in schemas, f"channel {cid} names unknown schema {sid}"
    return {"chunks": len(chunks), "messages": sum(counts.values()), "channels": len(channels),
            "metadata": len(metadata), "topics": {channels[c][1]: k for c, k in counts.items()},
            "schemas": {s[0]: s[1] for s in schemas.values()},
            "channel_schema": {t: schemas[s][0] if s else None for s, t, _e in channels.values()},
            "data_crc": struct.unpack_from("<I", buf, data_end_at + 9)[0]}


def check_with_mcap_reader(path) -> dict:
    """Read every message through the mcap package's indexed (seeking) reader, CRCs checked,
    in log-time order (which uses the message indexes); {topic: messages}."""
    from mcap.reader import make_reader
    out: dict[str, int] = {}
    with open(path, "rb") as f:
        r = make_reader(f, validate_crcs=True)
        assert r.get_summary() is not None
        last = None
        for _s, ch, m in r.iter_messages(log_time_order=True):
            assert last is None or m.log_time >= last
            last = m.log_time
            out[ch.topic] = out.get(ch.topic, 0) + 1
    return out


def conforms(path) -> dict:
    """Both checks; the two must agree on the messages per topic."""
    rep = check_layout(path)
    assert check_with_mcap_reader(path) == rep["topics"]
    return rep
