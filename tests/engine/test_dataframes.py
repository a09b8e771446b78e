"""The DataFrame API: stillpoint.read (samples with a time index: UTC when the zone is known,
naive device time otherwise; calibration and resampling) and stillpoint.tables."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np
import pytest

import stillpoint

if os.environ.get("CI") != "true":
    pd = pytest.importorskip("pandas", reason="pandas (the 'pandas' extra) is not installed")
else:  # CI installs the test extra, which has pandas: never skipped there
    import pandas as pd

FUZZ = Path(__file__).parents[1] / "data" / "fuzz"
GOOD = FUZZ / "ax3_unpacked_40_sectors.cwa"


def _raw(path, **kw):
    from stillpoint.drivers import open_recording
    t, a, temp = [], [], []
    with open_recording(path, **kw) as src:
        for b in src:
            t.append(b.time_at(np.arange(b.n)))
            a.append(b.accel_g())
            temp.append(b.temperature_per_sample())
    return np.concatenate(t), np.concatenate(a), np.concatenate(temp)


def test_read_gives_every_sample_on_a_naive_device_clock_without_a_zone():
    df = stillpoint.read(GOOD)
    t, a, _ = _raw(GOOD)
    assert list(df.columns) == ["x", "y", "z", "temperature_c"]
    assert df.index.name == "time_local" and df.index.tz is None
    assert np.array_equal(df.index.asi8, t)
    assert np.allclose(df[["x", "y", "z"]].to_numpy(), a, atol=1e-6)
    assert df.attrs["timezone"] == "device local time, zone unknown"


def test_read_with_a_zone_is_utc():
    local = stillpoint.read(GOOD)
    utc = stillpoint.read(GOOD, timezone="+02:00")
    assert str(utc.index.tz) == "UTC" and utc.index.name == "time"
    # the device clock read 2 h ahead of UTC
    assert (local.index[0] - utc.index[0].tz_localize(None)) == pd.Timedelta(hours=2)


def test_read_applies_a_given_estimate():
    est = {"status": "ok", "reason": "test", "offset": [0.01, -0.02, 0.03],
           "scale": [1.01, 0.99, 1.02], "tempoffset": [0.0, 0.0, 0.0], "temperature_ref": 25.0}
    raw = stillpoint.read(GOOD)
    cal = stillpoint.read(GOOD, calibrate=est)
    want = (raw[["x", "y", "z"]].to_numpy(np.float64) + est["offset"]) * est["scale"]
    assert np.allclose(cal[["x", "y", "z"]].to_numpy(), want, atol=1e-5)
    assert cal.attrs["calibration"]["offset"] == est["offset"]


def test_resample_interpolates_onto_a_grid_that_does_not_depend_on_blocks():
    raw = stillpoint.read(GOOD)
    df = stillpoint.read(GOOD, resample=10.0)
    step = 100_000_000
    assert np.all(df.index.asi8 % step == 0) and np.all(np.diff(df.index.asi8) == step)
    t = raw.index.asi8
    assert df.index.asi8[0] >= t[0] and df.index.asi8[-1] <= t[-1]
    # the same as interpolating the whole recording at once (the file is read in blocks)
    want = np.interp(df.index.asi8.astype(np.float64), t.astype(np.float64),
                     raw["x"].to_numpy(np.float64))
    assert np.allclose(df["x"].to_numpy(), want, atol=1e-5)
    assert len(df) == pytest.approx((t[-1] - t[0]) / step, abs=2)


def test_tables_of_an_mcap_and_of_the_recording_agree(tmp_path):
    from stillpoint.tools.cli import main
    mcap = tmp_path / "a.mcap"
    # (stillpoint.tables of a recording computes no sleep: the run that is compared neither)
    assert main(["process", str(GOOD), "-o", str(mcap), "-q", "--no-sleep"]) == 0
    t = stillpoint.tables(mcap)
    assert set(t) == {"epochs", "days"}
    ep = t["epochs"]
    assert ep.index.name == "time_local" and "enmo_mg" in ep.columns
    assert len(ep) == sum(1 for _ in __import__("gzip").open(tmp_path / "a.epochs.csv.gz", "rt")) - 1
    again = stillpoint.tables(GOOD)  # processed on the fly, in a temporary folder
    pd.testing.assert_frame_equal(again["epochs"], ep)
    # the night table is read when the run wrote one
    (tmp_path / "a.nights.csv").write_text("night,sleep_hours\n2025-01-01,7.5\n")
    assert stillpoint.tables(mcap)["nights"]["sleep_hours"].tolist() == [7.5]


def test_without_pandas_one_clear_error(monkeypatch):
    from stillpoint.engine.core.errors import StillpointError
    monkeypatch.setitem(sys.modules, "pandas", None)
    with pytest.raises(StillpointError, match=r"pip install 'stillpoint\[pandas\]'"):
        stillpoint.read(GOOD)
