"""The dock fits a 1,300 px wide window. The stylesheet lets the actions and progress cells wrap
(the rest of the dock row does not), and in a real headless browser (Debian's chromium through
chromedriver and Selenium) the dock page as the station serves it (its own stylesheet, a live
dock with the action forms) lays out every actions cell inside the window, with nothing to
scroll sideways, for rows with the longest actions (configure with subject and code, configure
again, verify again and clear) and a long detail line.

The browser test skips (with the reason) where chromium, chromedriver or selenium is missing,
except in CI, where it fails instead (the rule of the dashboard's end-to-end browser test)."""

from __future__ import annotations

import os
import re
from pathlib import Path

import pytest
from browser import chrome, missing

from stillpoint.engine.station.web import pages

CSS = Path(pages.__file__).parent / "static" / "dashboard.css"
WIDTH = 1300


def _rows() -> list[dict]:
    base = {"device_type": "AX3", "battery_pct": 87, "clock_offset_s": -1.4, "mbps": 9.83,
            "total_bytes": 512_000_000, "done_bytes": 512_000_000}
    return [
        {**base, "device_id": 10001, "slot": "usb-0000:00:14.0-1.2", "state": "cleared",
         "reason": "512.0 MB, 0 bad sectors, SHA-256 3f1c9a0b2d4e5f60; cleared; calibration "
                   "offset +12.1/-3.4/+8.8 mg, gain 1.003/0.998/1.001 (van Hees 2014, 412 points)"},
        {**base, "device_id": 10002, "slot": "usb-0000:00:14.0-1.3", "state": "configured",
         "configured_session": 2, "next_session": 3,
         "reason": "session 2, start 2026-11-29T07:23:36"},
        {**base, "device_id": 10003, "slot": "usb-0000:00:14.0-1.4", "state": "verified",
         "session": 1, "reason": "512.0 MB, 2 bad sectors re-read and patched"},
        {**base, "device_id": 10004, "slot": "usb-0000:00:14.0-1.5", "state": "error",
         "session": 4, "reason": "AX3-10004: the device stopped answering during the download"},
    ]


def _rule(css: str, selector: str) -> str:
    m = re.search(re.escape(selector) + r"\s*\{([^}]*)\}", css)
    return m.group(1) if m else ""


def test_actions_and_progress_cells_wrap_and_the_rest_does_not():
    frag = pages.dock_fragment(_rows(), {"free_bytes": 2.1e11, "downloads_fit": 380},
                               token="t" * 32, live=True)
    assert frag.count("<td class=actions>") == 4 and frag.count("<td class=progress>") == 4
    css = CSS.read_text()
    assert "nowrap" in _rule(css, "#dock td")
    for cell in ("#dock td.actions", "#dock td.progress"):
        assert re.search(r"white-space:\s*normal", _rule(css, cell)), cell
    assert "inline-block" in _rule(css, "#dock td.actions form.act")


def test_dock_actions_fit_a_1300_px_window(tmp_path):
    why = missing()
    if why:
        if os.environ.get("CI"):
            pytest.fail(f"the dock's layout test must run in CI: {why}", pytrace=False)
        pytest.skip(f"the dock's layout test needs a browser: {why}")
    frag = pages.dock_fragment(_rows(), {"free_bytes": 2.1e11, "downloads_fit": 380},
                               token="t" * 32, live=True)
    page = pages.dock_page(frag, folder="/data/station/out", live=True, read_only=False,
                           code="SP1_100_8_0_+2h_+7d_inc_10")
    page = page.replace("<link rel=stylesheet href='/static/dashboard.css'>",
                        f"<style>{CSS.read_text()}</style>")
    assert "<style>" in page and "/action/configure/AX3-10001" in page
    html = tmp_path / "dock.html"
    html.write_text(page, encoding="utf-8")

    drv = chrome(WIDTH, 900)
    try:
        drv.set_page_load_timeout(30)
        drv.get(html.as_uri())
        inner = drv.execute_script("return window.innerWidth")
        assert WIDTH - 40 <= inner <= WIDTH, inner  # the window is the width under test
        view = drv.execute_script("return document.documentElement.clientWidth")
        cells = drv.execute_script(
            "return Array.from(document.querySelectorAll('#dock tbody tr')).map(function (tr) {"
            "  var c = tr.lastElementChild, r = c.getBoundingClientRect();"
            "  var b = Array.from(c.querySelectorAll('button, input:not([type=hidden])'))"
            "    .map(function (e) { return e.getBoundingClientRect().right; });"
            "  return [tr.dataset.device, r.right, Math.max.apply(null, b.concat([0]))]; })")
        assert len(cells) == 4 and all(n for _, _, n in cells[:3]), cells
        for device, right, controls in cells:
            assert right <= view and controls <= view, (device, right, controls, view)
        scroll = drv.execute_script("return document.documentElement.scrollWidth")
        assert scroll <= view, (scroll, view)
    finally:
        drv.quit()
