"""The dock, the device page and the handover sheet give a device's recording window and any
time in a recorded line in ISO 8601 (``2026-11-29T07:23:36``), never the firmware's
``2026/11/29,07:23:36``, also for lines a ledger recorded before the station spoke ISO."""

from __future__ import annotations

import re

from stillpoint.drivers.ax.protocol import display_time, display_times
from stillpoint.engine.station.web import pages

FIRMWARE = re.compile(r"\d{4}/\d\d/\d\d,\d\d:\d\d:\d\d")


def _hist() -> dict:
    settings = {"session": 2, "rate_hz": 100, "range_g": 8, "gyro_dps": 0,
                "start": "2026/11/29,07:23:36", "stop": "2026/12/06,07:23:36",
                "metadata": {"subject": "P-017"}, "battery_pct": 90, "clock_offset_s": 0.01}
    return {"device_type": "AX3", "device_id": 10001, "downloads": [], "clears": [], "actions": [],
            "configurations": [{"id": 1, "time": 1.8e9, "session_id": 2, "settings": settings,
                                "result": "ok",
                                "reason": "start 2026/11/29,07:23:36 is in the past"}],
            "events": [{"time": 1.8e9, "state": "configured",
                        "reason": "session 2, start 2026/11/29,07:23:36"}]}


def test_display_times_rewrites_every_firmware_time_in_a_line():
    assert display_time("2026/11/29,07:23:36") == "2026-11-29T07:23:36"
    assert display_times("session 2, start 2026/11/29,07:23:36; stop 2026/12/06,07:23:36") == \
        "session 2, start 2026-11-29T07:23:36; stop 2026-12-06T07:23:36"
    assert display_times("fw 48, battery 90 %, clock +0.1 s") == "fw 48, battery 90 %, clock +0.1 s"


def test_handover_sheet_gives_the_recording_window_in_iso():
    sheet = pages.sheet_page(_hist())
    assert "2026-11-29T07:23:36" in sheet and "2026-12-06T07:23:36" in sheet
    assert not FIRMWARE.search(sheet), FIRMWARE.search(sheet)


def test_dock_detail_gives_a_recorded_configure_line_in_iso():
    row = {"device_type": "AX3", "device_id": 10001, "state": "configured",
           "reason": "session 2, start 2026/11/29,07:23:36"}
    frag = pages.dock_fragment([row], {"free_bytes": 1e10, "downloads_fit": 3}, token=None,
                               live=False)
    assert "start 2026-11-29T07:23:36" in frag
    assert not FIRMWARE.search(frag), FIRMWARE.search(frag)


def test_device_page_gives_configurations_and_events_in_iso():
    class _Records:
        folder = "."

        def inside(self, path):
            return None

    page = pages.device_page(_Records(), _hist())
    assert "start 2026-11-29T07:23:36" in page and "stop 2026-12-06T07:23:36" in page
    assert not FIRMWARE.search(page), FIRMWARE.search(page)
