"""Headless Chromium for the dashboard's browser tests: where the browser and its driver are,
what is missing to run them, and a driver opened with the flags every such test uses."""

from __future__ import annotations

import os
import shutil

CHROMIUM = os.environ.get("STILLPOINT_CHROMIUM", "/usr/bin/chromium")
CHROMEDRIVER = shutil.which("chromedriver") or "/usr/bin/chromedriver"
FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
         "--disable-component-update", "--disable-sync", "--no-first-run")


def missing() -> str:
    """Why the browser tests cannot run here ("" when they can)."""
    why = []
    if not os.access(CHROMIUM, os.X_OK):
        why.append(f"no chromium at {CHROMIUM}")
    if not os.access(CHROMEDRIVER, os.X_OK):
        why.append("no chromedriver")
    try:
        import selenium  # noqa: F401
    except ImportError:
        why.append("selenium is not installed (pip install -e '.[test]')")
    return "; ".join(why)


def chrome(width: int = 1280, height: int = 900):
    """A headless Chromium driver with a window of ``width`` x ``height`` (the caller quits it)."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    opts = webdriver.ChromeOptions()
    opts.binary_location = CHROMIUM
    for f in FLAGS + (f"--window-size={width},{height}",):
        opts.add_argument(f)
    return webdriver.Chrome(service=Service(CHROMEDRIVER), options=opts)
