"""What takes the space in an MCAP log: bytes per record kind and per topic.

    python tools/benchmarks/mcap_size.py LOG.mcap [--source REC.cwa] [--level 1]

Prints the file's bytes by record kind (chunks, message indexes, chunk indexes, summary...), and
per topic: messages, payload bytes, record-header bytes, Message Index bytes and the payloads'
size when each topic is compressed alone (zstd at ``--level`` over 60 s of log time at a time, so
the figures add up to about what the chunks hold). With ``--source`` it also prints the log's size
as a multiple of the recording it was made from.
"""

from __future__ import annotations

import argparse
import collections
import os
import struct
import sys

RECORDS = {1: "header", 2: "footer", 3: "schema", 4: "channel", 5: "message", 6: "chunk",
           7: "message index", 8: "chunk index", 9: "attachment", 10: "attachment index",
           11: "statistics", 12: "metadata", 13: "metadata index", 14: "summary offset",
           15: "data end"}
MESSAGE_RECORD_OVERHEAD = 9 + 2 + 4 + 8 + 8  # opcode, length, channel, sequence, log and publish time
INDEX_ENTRY = 16  # log time and offset


def record_bytes(path) -> collections.Counter:
    """Bytes (record header included) of every record kind at the top level of the file."""
    out = collections.Counter()
    with open(path, "rb") as f:
        f.seek(8)  # magic
        while True:
            head = f.read(9)
            if len(head) < 9:
                break
            op, n = head[0], struct.unpack("<Q", head[1:])[0]
            out[RECORDS.get(op, f"op {op}")] += 9 + n
            if op == 2:
                break
            f.seek(n, os.SEEK_CUR)
    return out


def topic_bytes(path, level: int) -> dict:
    """topic -> [messages, payload bytes, payload bytes compressed alone per 60 s]."""
    import zstandard
    from mcap.reader import make_reader
    comp = zstandard.ZstdCompressor(level=level)
    out: dict = collections.defaultdict(lambda: [0, 0, 0])
    pending: dict = collections.defaultdict(list)
    minute: dict = {}
    with open(path, "rb") as f:
        for _s, ch, m in make_reader(f).iter_messages(log_time_order=False):
            t, k = ch.topic, m.log_time // 60_000_000_000
            if minute.get(t, k) != k:
                out[t][2] += len(comp.compress(b"".join(pending[t])))
                pending[t] = []
            minute[t] = k
            pending[t].append(m.data)
            out[t][0] += 1
            out[t][1] += len(m.data)
    for t, parts in pending.items():
        if parts:
            out[t][2] += len(comp.compress(b"".join(parts)))
    return dict(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("log")
    ap.add_argument("--source", help="the recording the log was made from (for the ratio)")
    ap.add_argument("--level", type=int, default=1, help="zstd level of the per-topic estimate")
    a = ap.parse_args(argv)
    size = os.path.getsize(a.log)
    print(f"{a.log}: {size / 1e6:.2f} MB")
    if a.source:
        print(f"  {size / os.path.getsize(a.source):.3f}x {a.source} "
              f"({os.path.getsize(a.source) / 1e6:.2f} MB)")
    print("by record kind:")
    for kind, n in sorted(record_bytes(a.log).items(), key=lambda kv: -kv[1]):
        print(f"  {kind:18s} {n / 1e6:10.2f} MB")
    print(f"by topic (payloads compressed alone, zstd {a.level}, 60 s at a time):")
    print(f"  {'topic':20s} {'messages':>10s} {'payload':>10s} {'headers':>9s} {'index':>9s} "
          f"{'zstd':>9s}")
    for t, (k, raw, z) in sorted(topic_bytes(a.log, a.level).items(), key=lambda kv: -kv[1][2]):
        print(f"  {t:20s} {k:10d} {raw / 1e6:7.2f} MB {k * MESSAGE_RECORD_OVERHEAD / 1e6:6.2f} MB "
              f"{k * INDEX_ENTRY / 1e6:6.2f} MB {z / 1e6:6.2f} MB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
