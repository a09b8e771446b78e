"""The messages of chosen topics of an MCAP log, and the check that an unfinished log recovers
to a prefix of the complete one (the two-core and child-process fault tests share it)."""

from __future__ import annotations

from mcap.reader import make_reader

from stillpoint.engine.recover import recover


def messages(path, topics) -> dict:
    """{topic: [(log_time, data), ...]} of ``topics`` in file order."""
    out: dict = {t: [] for t in topics}
    with open(path, "rb") as f:
        for _s, ch, m in make_reader(f).iter_messages(topics=list(topics), log_time_order=False):
            out[ch.topic].append((m.log_time, m.data))
    return out


def recovers_to_prefix(part, full, tmp_path, topics) -> dict:
    """Recover ``part`` (an unfinished log) and check its messages are a prefix of ``full``'s,
    raw samples included; return them."""
    fixed = tmp_path / "fixed.mcap"
    recover(part, fixed)
    got, ref = messages(fixed, topics), messages(full, topics)
    assert got["/raw/accel"]
    for t in topics:
        assert got[t] == ref[t][:len(got[t])], t
    return got
