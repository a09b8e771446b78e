"""The report page's layout: clock-time axes, warnings in full, legends inside their panels and
no label over another (checked on the drawn figure's boxes, not by eye)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from stillpoint.engine import report

if os.environ.get("CI") != "true":
    pytest.importorskip("matplotlib", reason="the report draws with matplotlib (the plot extra)")

FUZZ = Path(__file__).parents[1] / "data" / "fuzz"
GOOD = FUZZ / "ax3_unpacked_40_sectors.cwa"
LONG = ("calibrated: error 46.39 -> 0.56 mg on 11989 windows, autocal-c2; warning: temperature term "
        "imprecise (SE x 0.092, y 0.138, z 0.070 mg/degC > 0.05); window temperature p5-p95 "
        "30.0-32.9 degC over 246 independent blocks; largest term z -0.67 +- 0.07 mg/degC (9.6 SE "
        "from zero); Wald 172.7 against 16.266 (p = 0.001)): kept, as it is clearly not zero "
        "(dropping it would move its effect into the offsets); recording only 24.0 h (< 72 h first "
        "load): flagged short; the final words of the warning")


def test_clock_labels_and_ticks():
    assert report._clock_label(13.5) == "13:30" and report._clock_label(0) == "00:00"
    assert report._clock_label(24) == "24:00"
    ticks = report._clock_ticks(12.2, 15.4)  # about 3 h: every 30 min
    assert list(ticks[:2]) == [12.5, 13.0] and ticks[-1] == 15.0
    assert list(report._clock_ticks(9.1, 9.9)) == [9.25, 9.5, 9.75]


def test_a_long_calibration_warning_is_printed_in_full():
    rec = {"summary": {"calibration": {"status": "ok", "reason": LONG}}}
    text = report._qc_text(rec, [])
    flat = " ".join(text.split())
    assert "the final words of the warning" in flat and " ".join(LONG.split()) in flat
    assert max(len(ln) for ln in text.splitlines()) <= 110


@pytest.fixture(scope="module")
def page(tmp_path_factory):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from stillpoint.engine.tables import table_paths
    from stillpoint.tools.cli import main
    d = tmp_path_factory.mktemp("page")
    rec_path, mcap = d / "a.cwa", d / "a.mcap"  # 4 h of a simulated wrist: nonmovement windows
    assert main(["simulate", "-o", str(rec_path), "--days", "0.17", "--hz", "25", "-q"]) == 0
    assert main(["process", str(rec_path), "-o", str(mcap), "-q"]) == 0
    ep_path, days_path = table_paths(mcap)
    rec = report._mcap_records(mcap)
    rec.setdefault("summary", {}).setdefault("calibration", {})["reason"] = LONG
    ep, days = report._read_epochs(ep_path), report._read_days(days_path)
    windows, est = report._sphere(mcap, rec["summary"]["calibration"] if "offset" in
                                  rec["summary"]["calibration"] else None, rec.get("settings") or {})
    fig = report._draw(plt, ep, days, windows, est, rec, "title", 5.0)
    fig.canvas.draw()
    yield fig, fig.canvas.get_renderer()
    plt.close(fig)


@pytest.fixture(scope="module")
def week_page():
    """A drawn page of 8 days (synthetic epochs) whose calibration windows reach past the
    histogram's range."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np
    n_day, per = 8, 17280
    dates = [f"2025-03-{3 + i:02d}" for i in range(n_day)]
    hour = np.tile(np.arange(per) * 5 / 3600, n_day)
    rng = np.random.default_rng(1)
    ep = {"dates": dates, "date": np.repeat(dates, per), "hour": hour,
          "enmo_mg": rng.gamma(0.5, 40, n_day * per),
          "temp_local": (np.datetime64("2025-03-03T00:00:00")
                         + np.arange(n_day * per) * np.timedelta64(5, "s")),
          "temp_c": 30 + np.sin(hour)}
    for k in report._FLAG_COLUMNS:
        ep[k] = np.zeros(n_day * per, bool)
    days = [{"date": d, "valid_day": "1", "day_hours": "24", "wear_hours": "24",
             "timezone": "device local time, zone unknown"} for d in dates]
    v = rng.normal(size=(3000, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    v *= rng.normal(1.0, 0.05, (3000, 1))  # a fifth of them beyond +-60 mg
    windows = type("W", (), {"mean": v, "temperature": np.full(3000, 30.0),
                             "__len__": lambda self: 3000})()
    rec = {"summary": {"calibration": {"status": "ok", "reason": LONG}}}
    fig = report._draw(plt, ep, days, windows, None, rec, "week", 5.0)
    fig.canvas.draw()
    yield fig, fig.canvas.get_renderer()
    plt.close(fig)


@pytest.fixture(params=["page", "week_page"])
def any_page(request):
    return request.getfixturevalue(request.param)


def _overlap(a, b) -> bool:
    return a.x0 < b.x1 and b.x0 < a.x1 and a.y0 < b.y1 and b.y0 < a.y1


def test_day_rows_are_labelled_in_clock_time(page):
    fig, _ = page
    labels = [t.get_text() for t in fig.axes[0].get_xticklabels() if t.get_text()]
    assert labels and all(len(x) == 5 and x[2] == ":" for x in labels), labels


def test_no_text_over_another_and_everything_on_the_page(any_page):
    fig, r = any_page
    fb = fig.bbox
    texts = [t for t in fig.findobj(lambda o: hasattr(o, "get_text") and hasattr(o, "get_window_extent"))
             if t.get_text() and t.get_visible()]
    boxes = [(t.get_text(), t.get_window_extent(r)) for t in texts]
    for name, b in boxes:  # nothing cut at the page's edges (the long warning included)
        assert b.x0 >= fb.x0 - 1 and b.x1 <= fb.x1 + 1 and b.y0 >= fb.y0 - 1, name
    titles = [(a.title.get_text(), a.title.get_window_extent(r)) for a in fig.axes if a.title.get_text()]
    xlabels = [(a.xaxis.label.get_text(), a.xaxis.label.get_window_extent(r)) for a in fig.axes
               if a.xaxis.label.get_text()]
    for tn, tb in titles:
        for ln, lb in xlabels:
            assert not _overlap(tb, lb), (tn, ln)


def test_legends_fit_inside_their_panels(any_page):
    fig, r = any_page
    checked = 0
    for ax in fig.axes:
        leg = ax.get_legend()
        if leg is None or ax is fig.axes[0]:  # the day rows' legend sits above the first row
            continue
        lb, ab = leg.get_window_extent(r), ax.get_window_extent(r)
        assert lb.x0 >= ab.x0 - 1 and lb.x1 <= ab.x1 + 1, ax.get_title()
        checked += 1
    assert checked >= 1  # the calibration histogram's
