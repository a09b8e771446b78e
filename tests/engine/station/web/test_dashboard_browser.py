"""The dashboard in a real headless browser (Debian's chromium through chromedriver and Selenium),
end to end with the command line: `stillpoint device emulate --count 3 --faults bit-flip:2` and
`stillpoint station OUT --web 127.0.0.1:0 --clear-after-verify`; the dock shows every device reach
``cleared`` or ``error``; a retry is clicked and confirmed in the page; the device view and the
handover sheet render; then, with the station stopped, `stillpoint dashboard OUT` shows the same
devices and pages from the ledger alone. Screenshots are saved and checked to be non-blank.

Skips (with the reason) where chromium, chromedriver or selenium is missing, except in CI
(``CI`` set: ``.ci/run`` installs them), where it fails instead."""

from __future__ import annotations

import os
import re
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest
from browser import chrome, missing

MISSING = missing()
if MISSING:
    if os.environ.get("CI"):
        pytest.fail(f"the dashboard's browser test must run in CI: {MISSING}", pytrace=False)
    pytest.skip(f"the dashboard's browser test needs a browser: {MISSING}", allow_module_level=True)

from selenium.webdriver.common.by import By  # noqa: E402
from selenium.webdriver.support import expected_conditions as EC  # noqa: E402
from selenium.webdriver.support.ui import WebDriverWait  # noqa: E402

IDS = (10001, 10002, 10003)


def _cli(*args, env):
    return subprocess.Popen([sys.executable, "-m", "stillpoint", *args], env=env, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            start_new_session=True)


def _line(proc, pattern: str, timeout_s: float = 120.0) -> re.Match:
    """The first line of ``proc``'s output matching ``pattern`` (the lines before are kept)."""
    end = time.monotonic() + timeout_s
    seen = []
    while time.monotonic() < end:
        line = proc.stdout.readline()
        if not line:
            if proc.poll() is not None:
                break
            continue
        seen.append(line)
        m = re.search(pattern, line)
        if m:
            return m
    raise AssertionError(f"no line matching {pattern!r}; output:\n{''.join(seen)}")


def _stop(proc) -> None:
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGINT)
        try:
            proc.wait(20)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(5)


def _not_blank(png: Path) -> None:
    from PIL import Image
    im = Image.open(png).convert("L")
    lo, hi = im.getextrema()
    assert im.size[0] > 200 and hi - lo > 100, f"{png} looks blank"
    assert len(im.resize((160, 120)).getcolors(160 * 120)) > 8, f"{png} looks blank"


def _states(drv) -> dict:
    """Device -> state of the dock's rows, read in one script call (the live stream replaces
    the rows at any moment)."""
    return drv.execute_script(
        "var o = {}; document.querySelectorAll('#dock tbody tr').forEach(function (r) {"
        " o[r.dataset.device] = r.dataset.state; }); return o;")


def _text(drv, css: str) -> str:
    return drv.execute_script("var e = document.querySelector(arguments[0]);"
                              " return e ? e.innerText : '';", css)


@pytest.fixture
def browser():
    drv = chrome()
    drv.set_page_load_timeout(30)
    yield drv
    drv.quit()


def test_dock_devices_retry_sheet_and_ledger_only(browser, tmp_path):
    env = dict(os.environ, STILLPOINT_RUNTIME_DIR=str(tmp_path / "runtime"), PYTHONUNBUFFERED="1",
               STILLPOINT_HOME=str(tmp_path / "home"))  # the station's calibration store
    shots = Path(os.environ.get("STILLPOINT_SCREENSHOTS", tmp_path / "shots"))
    shots.mkdir(parents=True, exist_ok=True)
    out = tmp_path / "out"
    out.mkdir()  # the station never creates its output folder
    emu = _cli("device", "emulate", "--count", "3", "--faults", "bit-flip:2", "--days", "0.01",
               "--dir", str(tmp_path / "emu"), env=env)
    station = dash = None
    try:
        _line(emu, r"3 emulated device\(s\) attached")
        station = _cli("station", str(out), "--web", "127.0.0.1:0", "--clear-after-verify",
                       "--plain", env=env)
        url = _line(station, r"dashboard: (http://127\.0\.0\.1:\d+/\?token=\S+)").group(1)
        drv = browser
        drv.get(url)
        wait = WebDriverWait(drv, 90, poll_frequency=0.2)
        # the live stream brings each device to a final state with no reload
        wait.until(lambda d: (lambda s: len(s) == 3 and all(v in ("cleared", "error") for v in s.values()))(_states(d)))
        WebDriverWait(drv, 10).until(EC.text_to_be_present_in_element((By.ID, "live"), "connected"))
        text = _text(drv, "#dock")
        for i in IDS:
            assert str(i) in text
        assert re.search(r"\b(cleared|error)\b", text)
        drv.save_screenshot(str(shots / "dock.png"))
        _not_blank(shots / "dock.png")

        # a retry, confirmed in the page: its button appears once the device's flow has ended
        # (the tables and report are made after the clear)
        wait.until(EC.presence_of_element_located(
            (By.CSS_SELECTOR, "form[action='/action/retry/AX3-10001'] button")))
        drv.find_element(By.ID, "who").send_keys("browser-test")
        drv.execute_script("document.querySelector(\"form[action='/action/retry/AX3-10001'] "
                           "button\").click();")
        WebDriverWait(drv, 10).until(EC.alert_is_present())
        drv.switch_to.alert.accept()
        wait.until(EC.presence_of_element_located((By.CSS_SELECTOR, "p.msg")))
        assert "retry of AX3-10001 started" in drv.find_element(By.CSS_SELECTOR, "p.msg").text
        # a cleared device, run again, is found empty
        wait.until(lambda d: _states(d).get("AX3-10001") == "empty")
        db = sqlite3.connect(out / "stillpoint-ledger.sqlite")
        row = db.execute("SELECT action, who, origin, result FROM actions").fetchall()
        db.close()
        assert row == [("retry", "browser-test", row[0][2], "started")]
        assert row[0][2].startswith("127.0.0.1")

        # the device view and the handover sheet
        drv.find_element(By.LINK_TEXT, "10002").click()
        wait.until(EC.presence_of_element_located((By.ID, "deviceview")))
        assert drv.find_element(By.TAG_NAME, "h1").text == "AX3-10002"
        body = drv.find_element(By.ID, "deviceview").text
        assert "FORMAT QC" in body and "verified" in body
        assert len(drv.find_elements(By.CSS_SELECTOR, "svg.chart")) == 4
        drv.save_screenshot(str(shots / "device.png"))
        _not_blank(shots / "device.png")
        drv.find_element(By.LINK_TEXT, "handover sheet").click()
        wait.until(EC.presence_of_element_located((By.ID, "sheet")))
        assert "AX3-10002" in drv.find_element(By.TAG_NAME, "h1").text
        assert "Cleared after verification" in drv.find_element(By.ID, "sheet").text
        drv.save_screenshot(str(shots / "sheet.png"))
        _not_blank(shots / "sheet.png")
        _stop(station)
        assert station.returncode in (0, 2)

        # the station stopped: the same pages from the ledger alone
        dash = _cli("dashboard", str(out), "--web", "127.0.0.1:0", env=env)
        url = _line(dash, r"dashboard: (http://127\.0\.0\.1:\d+/)\?token=").group(1)
        drv.get(url)
        wait.until(EC.presence_of_element_located((By.ID, "dock")))
        states = _states(drv)
        assert set(states) == {f"AX3-{i}" for i in IDS}
        assert all(v in ("cleared", "error", "empty") for v in states.values()), states
        assert "from the ledger" in drv.find_element(By.TAG_NAME, "header").text
        drv.get(url + "device/AX3-10003")
        assert drv.find_element(By.TAG_NAME, "h1").text == "AX3-10003"
    finally:
        for p in (dash, station, emu):
            if p is not None:
                _stop(p)
