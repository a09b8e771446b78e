"""A station killed (SIGKILL of its pid, so its download workers must end by themselves) at every
state boundary, then restarted: no worker outlives it, no device is stranded, no data is lost
(``tools/kill_station.py``; its ``--random`` trials kill at random times too)."""

from __future__ import annotations

import pytest

from stillpoint.engine.station.ledger import KILL_STEPS, KILL_STEPS_CONFIGURE
from stillpoint.tools.kill_station import trial


@pytest.mark.parametrize("step", KILL_STEPS + KILL_STEPS_CONFIGURE)
def test_killed_at_a_boundary_then_restarted(tmp_path, step):
    r = trial(tmp_path / "t", kill_at=step, configure=step in KILL_STEPS_CONFIGURE)
    assert r["killed"], f"the station never reached {step}"
    assert (r["orphans"], r["stranded"], r["lost"]) == (0, 0, 0), r.get("log")
    assert r["restart_rc"] == 0, r.get("log")
