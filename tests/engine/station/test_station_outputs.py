"""The station's outputs beyond the raw copy and its log: the epoch/day tables and the report per
verified download, the calibration prior from the store (recorded in the ledger and the log),
and a product that fails never holds back the download or its clear."""

from __future__ import annotations

import json

from stillpoint.drivers.ax.discovery import EmulatedBackend
from stillpoint.engine.calibration import CalibrationEstimate, CalibrationStore
from stillpoint.engine.station.flow import StationOptions
from stillpoint.engine.station.ledger import Ledger
from stillpoint.engine.station.station import Station
from stillpoint.tools.cli import main

from station_fixtures import emu, runtime  # noqa: F401

STEM = "AX3-10001_1"


def _run(out, **kw) -> int:
    import io
    buf = io.StringIO()
    with Station(StationOptions(str(out), inline=True, **kw), EmulatedBackend(), tty=False,
                 out=buf, poll_s=0.05) as st:
        rc = st.run(once=True)
    _run.text = buf.getvalue()
    return rc


def _products(out) -> dict:
    lg = Ledger(out)
    try:
        return {p[1]: (p[3], p[4]) for p in lg.products()}
    finally:
        lg.close()


def test_station_writes_the_tables_and_report_of_each_verified_download(emu, tmp_path, capsys):
    emu(10001)
    out = tmp_path / "out"
    out.mkdir()
    assert main(["station", str(out), "--once", "--plain"]) == 0
    text = capsys.readouterr().out
    assert "AX3 10001 [emu-1] outputs: tables written, report written" in text
    for name in (".epochs.csv.gz", ".days.csv", ".report.png", ".report.html"):
        assert (out / f"{STEM}{name}").stat().st_size > 0, name
    days = (out / f"{STEM}.days.csv").read_text().splitlines()
    assert days[0].startswith("date") or "date" in days[0].split(",")[0:3]
    assert len(days) >= 2
    assert (out / f"{STEM}.report.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    got = _products(out)
    assert got["tables"] == ("written", None) and got["report"] == ("written", None)


def test_existing_products_are_kept_and_made_when_missing_on_the_next_visit(emu, tmp_path):
    """A station stopped before the products: the device found already downloaded gets them;
    one that is already there is kept, never replaced."""
    emu(10001)
    out = tmp_path / "out"
    out.mkdir()
    assert _run(out, products=False) == 0
    assert not (out / f"{STEM}.days.csv").exists()
    (out / f"{STEM}.report.png").write_bytes(b"mine")
    assert _run(out) == 0
    assert "already downloaded" in _run.text
    assert (out / f"{STEM}.days.csv").exists()
    assert (out / f"{STEM}.report.png").read_bytes() == b"mine"
    got = _products(out)
    assert got["tables"][0] == "written" and got["report"][0] == "kept"


def test_no_matplotlib_means_no_report_said_in_one_line_and_no_failure(emu, tmp_path, monkeypatch):
    from stillpoint.engine import report
    from stillpoint.engine.report import ReportUnavailableError

    def missing():
        raise ReportUnavailableError("the report needs matplotlib, an optional extra")
    monkeypatch.setattr(report, "require_matplotlib", missing)
    emu(10001)
    out = tmp_path / "out"
    out.mkdir()
    assert _run(out) == 0
    lines = [x for x in _run.text.splitlines() if "outputs:" in x]
    assert len(lines) == 1 and "tables written, report skipped (the report needs matplotlib" in lines[0]
    assert (out / f"{STEM}.days.csv").exists() and not (out / f"{STEM}.report.png").exists()
    assert _products(out)["report"] == ("skipped", "the report needs matplotlib, an optional extra")


def test_a_failed_product_never_unverifies_or_blocks_the_clear(emu, tmp_path, monkeypatch):
    import stillpoint.engine.workflows.tables_from_mcap as tables

    def broken(*a, **k):
        raise OSError(28, "No space left on device", str(tmp_path / "out" / f"{STEM}.epochs.csv.gz"))
    monkeypatch.setattr(tables, "tables_from_mcap", broken)
    d = emu(10001)
    out = tmp_path / "out"
    out.mkdir()
    assert _run(out, clear_after_verify=True) == 0
    assert len(d.clears) == 1  # cleared all the same
    lg = Ledger(out)
    try:
        (dl,) = lg.downloads()
        assert dl.state == "verified" and dl.verified
    finally:
        lg.close()
    state, reason = _products(out)["tables"]
    assert state == "failed" and "no space left on device" in reason and STEM in reason
    assert "outputs: tables failed (" in _run.text


def _calibration_messages(mcap) -> list:
    from mcap.reader import make_reader
    with open(mcap, "rb") as f:
        r = make_reader(f)
        msgs = [(m.log_time, json.loads(m.data))
                for _, _, m in r.iter_messages(topics=["/calibration"])]
        meta = {m.name: m.metadata for m in r.iter_metadata()}
        first_raw = next(m.log_time for _, _, m in r.iter_messages(topics=["/raw/accel"]))
    return msgs, meta, first_raw


def test_the_log_is_corrected_from_its_first_sample_with_the_stores_estimate(emu, tmp_path):
    store = CalibrationStore(tmp_path / "store")
    prior = CalibrationEstimate(offset=[0.02, -0.01, 0.005], scale=[1.01, 0.99, 1.0],
                                status="ok", reason="an earlier wear", method="autocal-c1",
                                error_before_mg=12.0, error_after_mg=2.0, windows=400,
                                fit_start_ns=0, fit_end_ns=int(7 * 86400e9))
    store.add(prior, device_key="AX3-10001", source="earlier.cwa")
    emu(10001)
    emu(10002)
    out = tmp_path / "out"
    out.mkdir()
    assert _run(out, store=str(tmp_path / "store")) == 0
    # the device the store knows: corrected with its estimate from the first sample
    msgs, meta, first_raw = _calibration_messages(out / f"{STEM}.mcap")
    t0, first = msgs[0]
    assert t0 <= first_raw and first["applied"] is True
    assert first["offset"] == [0.02, -0.01, 0.005] and first["scale"] == [1.01, 0.99, 1.0]
    used = json.loads(meta["station"]["calibration_prior"])
    assert used["source"] == "store" and used["device_key"] == "AX3-10001"
    assert used["fitted_on"].startswith("1970-01-01T00:00:00") and used["error_after_mg"] == 2.0
    lg = Ledger(out)
    try:
        by_id = {d.device_id: d.id for d in lg.downloads()}
        assert lg.prior_of(by_id[10001])["source"] == "store"
        other = lg.prior_of(by_id[10002])
        assert other["source"] == "none" and "holds no estimate of this device" in other["detail"]
        stored = {p[0]: (p[1], p[3]) for p in lg.products() if p[1] == "calibration store"}
        # no refit in 15 min of data: the estimate in force is the store's own, not stored again
        assert stored[by_id[10001]] == ("calibration store", "kept")
    finally:
        lg.close()
    # the device it does not know: identity until the first refit, nothing applied at the start
    msgs2, meta2, _ = _calibration_messages(out / "AX3-10002_1.mcap")
    assert not any(m["applied"] for _, m in msgs2)
    assert json.loads(meta2["station"]["calibration_prior"])["source"] == "none"
    assert len(store.records("AX3-10001")) == 1


def test_without_a_store_the_ledger_says_so(emu, tmp_path):
    emu(10001)
    out = tmp_path / "out"
    out.mkdir()
    assert _run(out) == 0
    lg = Ledger(out)
    try:
        (dl,) = lg.downloads()
        assert lg.prior_of(dl.id)["source"] == "none"
        assert "no calibration store" in lg.prior_of(dl.id)["detail"]
    finally:
        lg.close()


def test_a_verified_downloads_refit_goes_to_the_store_for_the_next_download(tmp_path):
    """The final estimate of a download (a refit was accepted) is added to the store, with the
    raw copy as its source; a failed fit is not."""
    from types import SimpleNamespace
    from stillpoint.engine.station.flow import DeviceFlow
    att = SimpleNamespace(device_type="AX3", device_id=10001, serial="CWA17_10001")
    flow = DeviceFlow(att, StationOptions(str(tmp_path), store=str(tmp_path / "store")), None)
    fit = CalibrationEstimate(offset=[0.01, 0, 0], status="ok", method="autocal-c1",
                              fit_start_ns=0, fit_end_ns=int(12 * 3600e9), error_after_mg=3.0)
    row = flow._store_final({"calibration": fit.to_dict()}, str(tmp_path / "AX3-10001_1.cwa"))
    assert row["result"] == "written"
    store = CalibrationStore(tmp_path / "store")
    (rec,) = store.records("AX3-10001")
    assert rec["source"].endswith("AX3-10001_1.cwa")
    assert store.prior_for("AX3-10001").offset.tolist() == [0.01, 0, 0]
    failed = CalibrationEstimate.identity("online: no estimate accepted yet")
    row = flow._store_final({"calibration": failed.to_dict()}, "x.cwa")
    assert row["result"] == "skipped" and len(store.records("AX3-10001")) == 1
    flow.opts.store = None
    assert flow._store_final({"calibration": fit.to_dict()}, "x.cwa") is None


def test_products_stopped_with_the_station_are_not_recorded_and_made_next_time(emu, tmp_path,
                                                                                monkeypatch):
    import threading
    import stillpoint.engine.workflows.tables_from_mcap as tables
    real = tables.tables_from_mcap
    started, release = threading.Event(), threading.Event()

    def slow(*a, **k):
        started.set()
        release.wait(20)
        return real(*a, **k)
    monkeypatch.setattr(tables, "tables_from_mcap", slow)
    emu(10001)
    out = tmp_path / "out"
    out.mkdir()
    import io
    stop = threading.Event()
    with Station(StationOptions(str(out), inline=True), EmulatedBackend(), tty=False,
                 out=io.StringIO(), poll_s=0.05) as st:
        th = threading.Thread(target=st.run, kwargs={"stop": stop})
        th.start()
        assert started.wait(30)
        stop.set()  # Ctrl-C while the tables are being made
        th.join(30)
        (f,) = st.flows.values()
        f.finished.wait(10)
        assert f.state == "verified" and f.outputs is None
        release.set()
        f.products_worker._thread.join(30)  # a thread cannot be killed as a worker process is
    assert _products(out) == {}  # nothing recorded as failed
    monkeypatch.setattr(tables, "tables_from_mcap", real)
    assert _run(out) == 0 and "already downloaded" in _run.text
    got = _products(out)
    assert got["tables"][0] == "kept" and got["report"][0] == "written"
