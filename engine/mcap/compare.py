"""Compare two stillpoint MCAP logs topic by topic (message payloads, bit for bit).

Used by ``stillpoint replay --check``: a replay with the original settings must reproduce the
corrected stream, the epoch metrics and every calibration estimate exactly.
"""

from __future__ import annotations

import hashlib
from itertools import zip_longest

from .stream import iter_topic_messages

REPLAY_TOPICS = ("/corrected/accel", "/metrics/epoch", "/calibration", "/raw/accel",
                 "/view/accel")


def topic_digests(path, topics=REPLAY_TOPICS) -> dict:
    """{topic: (messages, sha256 of every (log_time, payload))} in file order."""
    out = {t: [0, hashlib.sha256()] for t in topics}
    with open(path, "rb") as f:  # streamed: one chunk in memory at a time
        for topic, log_time, data in iter_topic_messages(f, topics):
            d = out[topic]
            d[0] += 1
            d[1].update(log_time.to_bytes(8, "little"))
            d[1].update(len(data).to_bytes(8, "little"))
            d[1].update(data)
    return {t: (n, h.hexdigest()) for t, (n, h) in out.items()}


def compare(a, b, topics=REPLAY_TOPICS) -> dict:
    """{topic: {"identical": bool, "messages": (na, nb)}}."""
    da, db = topic_digests(a, topics), topic_digests(b, topics)
    return {t: {"identical": da[t] == db[t], "messages": (da[t][0], db[t][0])} for t in topics}


def first_difference(a, b, topic) -> int | None:
    """Index of the first differing message of ``topic`` (None when identical)."""
    with open(a, "rb") as fa, open(b, "rb") as fb:
        ia = iter_topic_messages(fa, [topic])
        ib = iter_topic_messages(fb, [topic])
        for i, (x, y) in enumerate(zip_longest(ia, ib)):
            if x is None or y is None or x[1] != y[1] or bytes(x[2]) != bytes(y[2]):
                return i
    return None
