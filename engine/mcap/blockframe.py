"""Message records of many messages framed at once into one preallocated buffer.

``CdrLayout`` computes, for k messages of one CDR type at once, the byte offset of every field
(the alignment rules of engine/mcap/schemas.py, evaluated on arrays of positions: padding
depends on the lengths of the sequences before a field) and the payload sizes. ``put_*`` then
write the fields at those offsets: small fields (headers, scalars, sequence counts, per-unit
arrays) by one numpy scatter per field over all messages; per-sample sequences (thousands of
elements each) by one slice copy per message, which is cheaper than any element scatter.
Bytes not written are padding and stay zero (the buffer is zeroed), as ``CdrType.encode``
writes them. ``record_headers`` frames the Message records (opcode, length, channel, sequence,
log and publish time) of all messages in one structured array.
"""

from __future__ import annotations

import numpy as np

from . import records as rec
from .schemas import CdrType, _PRIM, _parse

RECORD_HEADER = np.dtype([("op", "u1"), ("len", "<u8"), ("cid", "<u2"), ("seq", "<u4"),
                          ("log", "<u8"), ("pub", "<u8")])
assert RECORD_HEADER.itemsize == rec.MESSAGE_HEADER.size
HEAD = RECORD_HEADER.itemsize

_TIME = np.dtype([("sec", "<i4"), ("nsec", "<u4")])


def scatter(buf: np.ndarray, at: np.ndarray, rows: np.ndarray) -> None:
    """``buf[at[i] : at[i] + w] = rows[i]`` for every i (rows: (k, w) uint8), one numpy call."""
    k, w = rows.shape
    if k and w:
        buf[(at[:, None] + np.arange(w, dtype=np.int64)).reshape(-1)] = rows.reshape(-1)


def scatter_runs(buf: np.ndarray, at: np.ndarray, src: np.ndarray, lens: np.ndarray) -> None:
    """Runs of bytes: ``src`` holds the runs one after another (``lens[i]`` bytes each); run i
    goes to ``buf[at[i]:]`` (one scatter: for short runs, e.g. a few sectors' values)."""
    total = int(src.shape[0])
    if total:
        starts = np.cumsum(lens) - lens
        buf[np.repeat(at - starts, lens) + np.arange(total, dtype=np.int64)] = src


def time_bytes(t_ns: np.ndarray) -> np.ndarray:
    """``builtin_interfaces/Time`` of each time as (k, 8) bytes (zeros outside int32 seconds,
    as ``CdrType.encode``)."""
    sec, nsec = np.divmod(np.asarray(t_ns, np.int64), 10**9)
    ok = (sec >= -2**31) & (sec < 2**31)
    a = np.zeros(sec.shape[0], _TIME)
    a["sec"] = np.where(ok, sec, 0)
    a["nsec"] = np.where(ok, nsec, 0)
    return a.view(np.uint8).reshape(-1, 8)


def _plan(cdr_type: CdrType) -> tuple:
    """``(head, rest)`` of a CDR type, computed once per type. ``head``: the structured dtype of
    the encapsulation header and the fields before the first sequence (their offsets are the
    same in every message: alignment padding is part of the dtype); ``rest``: ``(field, kind,
    dtype, elements)`` of the fields from the first sequence on."""
    plan = cdr_type.__dict__.get("_frame_plan")
    if plan is not None:
        return plan
    names, formats, offsets = ["enc"], ["<u4"], [0]
    pos, rest = 0, []
    for f, t in cdr_type.fields:
        if t == "time":
            dt, n = _TIME, 0
            align = 4
        else:
            base, n = _parse(t)
            dt = np.dtype(_PRIM[base])
            align = dt.itemsize
        if rest or n is None:
            rest.append((f, "time" if t == "time" else ("seq" if n is None else
                                                       ("prim" if n == 0 else "arr")), dt, n))
            continue
        pos += (-pos) % align
        names.append(f)
        formats.append(dt if not n else (dt, (n,)))
        offsets.append(pos + 4)
        pos += dt.itemsize * (n or 1)
    head = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": pos + 4})
    plan = cdr_type.__dict__["_frame_plan"] = (head, tuple(rest))
    return plan


class CdrLayout:
    """Field offsets (from the start of each payload) of k messages of ``cdr_type``."""

    def __init__(self, cdr_type: CdrType, k: int, seq_lens: dict):
        """``seq_lens``: field -> (k,) element counts of every sequence field."""
        self.type = cdr_type
        self.k = k
        self.head, rest = _plan(cdr_type)
        self.field = {}  # from the first sequence on: name -> (kind, dtype, data offsets (k,),
        # count offsets (k,) or None)
        pos = np.full(k, self.head.itemsize - 4, np.int64)
        for f, kind, dt, n in rest:
            size = 4 if kind == "time" else dt.itemsize
            if kind == "seq":
                cnt = np.asarray(seq_lens[f], np.int64)
                pos += (-pos) & 3
                cpos = pos + 4
                pos = pos + 4
                if size > 4:
                    pos += np.where(cnt > 0, (-pos) % size, 0)
                self.field[f] = ("seq", dt, pos + 4, cpos)
                pos = pos + cnt * size
            else:
                pos += (-pos) % size
                self.field[f] = (kind, dt, pos + 4, None)
                pos = pos + (8 if kind == "time" else size * max(n, 1))
        self.size = pos + 4  # payload bytes (with the encapsulation header)

    def put_head(self, buf, base, values: dict) -> None:
        """The encapsulation header and the fields before the first sequence (``values``: field
        -> a value, or one value or row per message; times in ns), one scatter for all."""
        a = np.zeros(self.k, self.head)
        a["enc"] = 0x100  # 00 01 00 00: CDR, little-endian
        for f in self.head.names[1:]:
            v = values[f]
            a[f] = time_bytes(v).view(_TIME).reshape(-1) if self.head[f] == _TIME else v
        scatter(buf, base, a.view(np.uint8).reshape(self.k, -1))

    def put_counts_of(self, buf, base, fields, counts) -> None:
        """The element counts of several sequence fields in one scatter (``counts[j]``: the
        (k,) counts of ``fields[j]``)."""
        at = np.concatenate([base + self.field[f][3] for f in fields])
        v = np.concatenate([np.asarray(c, "<u4") for c in counts])
        scatter(buf, at, v.view(np.uint8).reshape(-1, 4))

    def put_seq_runs_of(self, buf, base, fields, srcs, counts: np.ndarray) -> None:
        """Sequence fields whose messages take consecutive runs of ``srcs`` (short runs, the
        same counts in every field: e.g. a few sectors' values), all in one scatter."""
        at, data, lens = [], [], []
        for f, src in zip(fields, srcs):
            dt = self.field[f][1]
            data.append(np.ascontiguousarray(src, dt).view(np.uint8))
            at.append(base + self.field[f][2])
            lens.append(counts * dt.itemsize)
        scatter_runs(buf, np.concatenate(at), np.concatenate(data), np.concatenate(lens))

    def put_seq_slices(self, buf, base, f: str, src: np.ndarray, starts, counts) -> None:
        """A sequence field whose message i holds ``src[starts[i]:starts[i] + counts[i]]``
        (long runs: one slice copy each)."""
        dt = self.field[f][1]
        s = np.ascontiguousarray(src, dt).view(np.uint8)
        w = dt.itemsize
        at = (base + self.field[f][2]).tolist()
        for d, a, n in zip(at, starts, counts):
            buf[d:d + n * w] = s[a * w:(a + n) * w]


def put_rows(buf: np.ndarray, at: np.ndarray, stride: np.ndarray, rows: np.ndarray, starts,
             counts) -> None:
    """Consecutive sequence fields of one element type (e.g. x, y, z: int16[] each), message i
    holding ``rows[:, starts[i]:starts[i] + counts[i]]``: each field's data starts ``stride[i]``
    bytes after the previous one's (its count and padding between), so one 2-D copy per
    message writes them all (``at``: offsets of the first field's data)."""
    w = rows.dtype.itemsize
    k = rows.shape[0]
    b = np.ascontiguousarray(rows).view(np.uint8)
    for d, st, a, n in zip(at.tolist(), stride.tolist(), starts, counts):
        buf[d:d + k * st].reshape(k, st)[:, :n * w] = b[:, a * w:(a + n) * w]


def record_headers(cids: np.ndarray, seqs: np.ndarray, times: np.ndarray,
                   payload_sizes: np.ndarray) -> np.ndarray:
    """Message record framings (op, length, channel, sequence, log time, publish time) as
    (k, 31) bytes; ``times`` already clamped at 0 (publish time = log time)."""
    k = cids.shape[0]
    h = np.empty(k, RECORD_HEADER)
    h["op"] = rec.OP_MESSAGE
    h["len"] = rec.MESSAGE_OVERHEAD + payload_sizes
    h["cid"] = cids
    h["seq"] = (seqs & 0xFFFFFFFF).astype(np.uint32)
    h["log"] = times
    h["pub"] = times
    return h.view(np.uint8).reshape(k, HEAD)


def fixed_records(payloads: np.ndarray, cid: int, seq0: int, times: np.ndarray) -> np.ndarray:
    """Message records of fixed-size payloads (one structured row each) as one structured array
    (record framing then payload, packed): no per-record work at all."""
    k = payloads.shape[0]
    a = np.empty(k, np.dtype([("h", RECORD_HEADER), ("p", payloads.dtype)]))
    h = a["h"]
    h["op"] = rec.OP_MESSAGE
    h["len"] = rec.MESSAGE_OVERHEAD + payloads.dtype.itemsize
    h["cid"] = cid
    h["seq"] = (np.arange(seq0, seq0 + k, dtype=np.int64) & 0xFFFFFFFF).astype(np.uint32)
    h["log"] = times
    h["pub"] = times
    a["p"] = payloads
    return a


class VariableRecords:
    """The Message records of k messages of one CDR type (``layout``), back to back in one
    zeroed buffer: framing written here, payload fields by the caller (``base``: payload
    offsets; ``off``: record offsets, k + 1 of them; the payloads' head, ``CdrLayout.put_head``,
    is the caller's too)."""

    def __init__(self, layout: CdrLayout, cid: int, seq0: int, times: np.ndarray, slack: int = 0):
        """``slack``: zero bytes after the last record (room for ``put_rows`` regions)."""
        k = layout.k
        self.layout = layout
        self.off = np.zeros(k + 1, np.int64)
        np.cumsum(layout.size + HEAD, out=self.off[1:])
        self.buf = np.zeros(int(self.off[-1]) + slack, np.uint8)
        scatter(self.buf, self.off[:-1],
                record_headers(np.full(k, cid, np.int64), np.arange(seq0, seq0 + k, dtype=np.int64),
                               times, layout.size))
        self.base = self.off[:-1] + HEAD
