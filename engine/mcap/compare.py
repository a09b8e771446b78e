"""Compare two stillpoint MCAP logs topic by topic (message payloads, bit for bit).

Used by ``stillpoint replay --check``: a replay with the original settings must reproduce every
topic of the log exactly (raw accel and gyro, corrected stream, temperature, epoch metrics,
calibration estimates, QC).
"""

from __future__ import annotations

import hashlib

from .stream import iter_messages  # streamed: one chunk in memory at a time


def topic_digests(path, topics=None) -> dict:
    """{topic: (messages, sha256 of every (log_time, payload))} in file order; every topic of the
    file when ``topics`` is None. Chunk CRCs are checked (a damaged log is an error, not a diff)."""
    out = {t: [0, hashlib.sha256()] for t in (topics or ())}
    for topic, _i, msg in iter_messages(path, topics):
        d = out.setdefault(topic, [0, hashlib.sha256()])
        d[0] += 1
        d[1].update(msg.log_time.to_bytes(8, "little"))
        d[1].update(len(msg.data).to_bytes(8, "little"))
        d[1].update(msg.data)
    return {t: (n, h.hexdigest()) for t, (n, h) in out.items()}


def compare(a, b, topics=None) -> dict:
    """{topic: {"identical": bool, "messages": (na, nb)}} over ``topics``, or every topic that
    either log holds (a topic missing from one side counts 0 messages there)."""
    da, db = topic_digests(a, topics), topic_digests(b, topics)
    names = list(topics) if topics else sorted(set(da) | set(db))
    empty = (0, hashlib.sha256().hexdigest())
    return {t: {"identical": da.get(t, empty) == db.get(t, empty),
                "messages": (da.get(t, empty)[0], db.get(t, empty)[0])} for t in names}

