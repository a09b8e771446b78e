"""Compare two stillpoint MCAP logs topic by topic (message payloads, bit for bit).

Used by ``stillpoint replay --check``: a replay with the original settings must reproduce the
corrected stream, the epoch metrics and every calibration estimate exactly.
"""

from __future__ import annotations

import hashlib
from itertools import zip_longest

from mcap.reader import make_reader

REPLAY_TOPICS = ("/corrected/accel", "/metrics/epoch", "/calibration", "/raw/accel")


def topic_digests(path, topics=REPLAY_TOPICS) -> dict:
    """{topic: (messages, sha256 of every (log_time, payload))} in file order."""
    out = {t: [0, hashlib.sha256()] for t in topics}
    with open(path, "rb") as f:
        for _s, ch, msg in make_reader(f).iter_messages(topics=list(topics), log_time_order=False):
            d = out[ch.topic]
            d[0] += 1
            d[1].update(msg.log_time.to_bytes(8, "little"))
            d[1].update(len(msg.data).to_bytes(8, "little"))
            d[1].update(msg.data)
    return {t: (n, h.hexdigest()) for t, (n, h) in out.items()}


def compare(a, b, topics=REPLAY_TOPICS) -> dict:
    """{topic: {"identical": bool, "messages": (na, nb)}}."""
    da, db = topic_digests(a, topics), topic_digests(b, topics)
    return {t: {"identical": da[t] == db[t], "messages": (da[t][0], db[t][0])} for t in topics}


def first_difference(a, b, topic) -> int | None:
    """Index of the first differing message of ``topic`` (None when identical)."""
    with open(a, "rb") as fa, open(b, "rb") as fb:
        ia = make_reader(fa).iter_messages(topics=[topic], log_time_order=False)
        ib = make_reader(fb).iter_messages(topics=[topic], log_time_order=False)
        for i, (x, y) in enumerate(zip_longest(ia, ib)):
            if x is None or y is None or x[2].data != y[2].data or x[2].log_time != y[2].log_time:
                return i
    return None
