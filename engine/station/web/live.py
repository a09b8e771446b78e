"""The dock as the running station sees it, kept by a station listener (``Station.add_listener``).

``LiveDock()``: ``on_change(flow)`` copies the few fields the dock shows into a plain dict (no
I/O: it runs on the flow's thread and must be quick) and bumps ``version``; ``wait(version,
timeout)`` blocks a server-sent-events stream until something changed; ``rows()`` is a copy of the
rows, one per device serial, with an ETA from the copy's rate.
"""

from __future__ import annotations

import threading
import time
from typing import Optional


class LiveDock:
    def __init__(self):
        self._rows: dict[str, dict] = {}
        self._cond = threading.Condition()
        self.version = 0
        self.state_version = 0  # bumped on state changes only (not progress)

    def on_change(self, flow) -> None:
        att = flow.att
        row = {"serial": att.serial, "slot": att.slot, "device_id": att.device_id,
               "device_type": att.device_type, "state": flow.state, "reason": flow.reason,
               "info": flow.info, "done_bytes": flow.done_bytes, "total_bytes": flow.total_bytes,
               "mbps": flow.mbps, "detached": flow.detached, "session": flow.session,
               "configured_session": getattr(flow, "configured_session", None),
               "running": not flow.finished.is_set()}  # products run after the final state
        with self._cond:
            old = self._rows.get(att.serial)
            if old is None or (old["state"], old["reason"], old["detached"]) != \
                    (row["state"], row["reason"], row["detached"]):
                self.state_version += 1
                row["since"] = time.time()
            else:
                row["since"] = old.get("since", time.time())
            self._rows[att.serial] = row
            self.version += 1
            self._cond.notify_all()

    def rows(self) -> list[dict]:
        with self._cond:
            out = [dict(r) for r in self._rows.values()]
        for r in out:
            r["eta_s"] = eta_s(r)
        return out

    def wake(self) -> None:
        """Wake every waiting stream (the server is stopping)."""
        with self._cond:
            self.version += 1
            self._cond.notify_all()

    def wait(self, version: int, timeout: float) -> int:
        """Wait until ``version`` is passed (or ``timeout``); returns the current version."""
        with self._cond:
            self._cond.wait_for(lambda: self.version != version, timeout)
            return self.version


def eta_s(row: dict) -> Optional[float]:
    """Seconds left of a copy at its current rate, or None."""
    if row.get("state") != "downloading" or not row.get("mbps") or not row.get("total_bytes"):
        return None
    left = max(0, row["total_bytes"] - row["done_bytes"])
    return left / (row["mbps"] * 1e6)
