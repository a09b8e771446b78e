"""`stillpoint inspect` and `stillpoint export` on written files (both formats) and on every real file."""

from __future__ import annotations

import csv
import gzip
import json
import subprocess
import sys
import types

import numpy as np
import pytest

from stillpoint.drivers import open_recording
from stillpoint.drivers.geneactiv import GeneactivWriter
from stillpoint.engine.core.blocks import Block
from stillpoint.tools.cli import main
from stillpoint.engine.export import export_recording, format_fixed, format_scaled, format_time
from stillpoint.engine.inspection import inspect_recording, iso_utc

T0 = 1_700_000_000_000_000_000  # 2023-11-14T22:13:20Z


@pytest.fixture
def gna(tmp_path):
    p = tmp_path / "rec.bin"
    n = 3000
    rng = np.random.default_rng(3)
    t = T0 + np.round(np.arange(n) * 1e9 / (600 / 7)).astype(np.int64)
    a = rng.integers(-1500, 1500, (n, 3))
    w = GeneactivWriter(p, rate_hz=600 / 7, timezone="+02:00", serial="000123", volts=300, lux=800,
                        gains=(25000, 25000, 25000), offsets=(500, -500, 0))
    w.write(t, a, light_raw=np.arange(n) % 1024, button=(np.arange(n) % 7 == 0).astype(int),
            temperature_c=np.repeat(np.arange(10) + 20.0, 300), battery_v=4.1)
    w.close()
    return p, t, a


def run_cli(args, capsys):
    code = main(args)
    out, err = capsys.readouterr()
    return code, out, err


def test_inspect_json_geneactiv(gna, capsys):
    p, t, a = gna
    code, out, err = run_cli(["inspect", str(p), "--json"], capsys)
    assert code == 0 and err == ""
    d = json.loads(out)
    assert d["device_type"] == "GENEActiv" and d["device_id"] == "000123" and d["session_id"] is None
    assert d["samples"] == 3000
    assert d["sample_rate_nominal"] == pytest.approx(600 / 7)
    assert d["sample_rate_measured"] == pytest.approx(600 / 7, rel=1e-6)
    assert d["start"] == iso_utc(t[0]) == "2023-11-14T22:13:20.000000000Z"
    assert abs(d["end_ns"] - int(t[-1])) <= 1_000_000
    assert d["duration_s"] == pytest.approx((t[-1] - t[0]) / 1e9, abs=1e-3)
    assert d["pages"] == {"total": 10, "valid": 10, "skipped": 0}
    assert d["qc"] == [] and d["segments"] == 1
    assert d["temperature_range_c"] == [20.0, 29.0]
    assert d["timezone_offset_s"] == 7200
    assert d["channels"][:3] == ["accel_x", "accel_y", "accel_z"] and "button" in d["channels"]


def test_measured_rate_excludes_gaps_between_segments(tmp_path, capsys):
    p = tmp_path / "gap.bin"
    w = GeneactivWriter(p, rate_hz=50.0)
    t = T0 + np.arange(600) * 20_000_000
    w.write(t, np.zeros((600, 3), int))
    w.write(t + 3600 * 10**9 + 12_000_000, np.zeros((600, 3), int))  # one hour later
    w.close()
    d = inspect_recording(p)
    assert d["segments"] == 2 and d["samples"] == 1200
    assert d["sample_rate_measured"] == pytest.approx(50.0, rel=1e-9)
    assert [e["reason"] for e in d["qc"]] == ["time_jump"]
    assert d["duration_s"] > 3600


def test_inspect_text_and_header_only(gna, capsys):
    p, _, _ = gna
    code, out, _ = run_cli(["inspect", str(p)], capsys)
    assert code == 0
    assert "GENEActiv 000123" in out and "samples     3000" in out and "85.7143 Hz nominal" in out
    code, out, _ = run_cli(["inspect", str(p), "--header-only", "--json"], capsys)
    d = json.loads(out)
    assert "samples" not in d and d["header"]["gains"] == [25000, 25000, 25000]
    code, out, _ = run_cli(["inspect", str(p), "--header-only"], capsys)
    assert "Device Unique Serial Code" in out


def test_inspect_timezone_override(gna, capsys):
    """A zone that contradicts the GENEActiv header's (+02:00) is refused unless overridden."""
    p, t, _ = gna
    code, out, err = run_cli(["inspect", str(p), "--timezone", "+00:00"], capsys)
    assert code == 2 and out == "" and err.count("\n") == 1
    assert str(p) in err and "+02:00" in err and "--timezone-override" in err
    assert inspect_recording(p, timezone="+02:00")["start_ns"] == int(t[0])  # agrees: fine
    d = inspect_recording(p, timezone="+00:00", timezone_override=True)
    assert d["start_ns"] == int(t[0]) + 7200 * 10**9 and d["timezone"] == "+00:00"


def test_export_csv_geneactiv(gna, tmp_path, capsys):
    p, t, a = gna
    out = tmp_path / "o.csv"
    code, msg, err = run_cli(["export", str(p), "-o", str(out)], capsys)
    assert code == 0 and "3000 samples" in msg
    rows = list(csv.reader(out.open()))
    assert rows[0] == ["time", "x", "y", "z", "temperature", "light", "battery", "button"]
    assert len(rows) == 3001
    g = (a * 100.0 - np.array([500, -500, 0])) / 25000
    xyz = np.array([[float(v) for v in r[1:4]] for r in rows[1:]])
    np.testing.assert_allclose(xyz, g, atol=5e-7)
    assert rows[1][0] == "2023-11-14T22:13:20.000000Z"
    assert float(rows[301][4]) == 21.0 and float(rows[1][6]) == 4.1
    assert float(rows[2][5]) == pytest.approx(800 / 300, abs=1e-3)  # light raw 1 -> lux
    assert [int(r[7]) for r in rows[1:16]] == [1, 0, 0, 0, 0, 0, 0, 1, 0, 0, 0, 0, 0, 0, 1]
    assert not (tmp_path / "o.csv.partial").exists()


@pytest.mark.parametrize("mode", ["epoch", "ns"])
def test_export_csv_exact_times(gna, tmp_path, mode):
    p, t, _ = gna
    out = tmp_path / "o.csv.gz"
    export_recording(p, out, time_format=mode)
    with gzip.open(out, "rt") as f:
        rows = list(csv.reader(f))
    src = open_recording(p)
    ref = Block.concat(list(src)).time_ns
    if mode == "ns":
        got = np.array([int(r[0]) for r in rows[1:]])
    else:
        got = np.array([int(r[0].replace(".", "")) for r in rows[1:]])
        assert all(len(r[0].split(".")[1]) == 9 for r in rows[1:5])
    np.testing.assert_array_equal(got, ref)


def test_export_npz_geneactiv(gna, tmp_path):
    p, t, a = gna
    out = tmp_path / "o.npz"
    rep = export_recording(p, out)
    assert rep["samples"] == 3000
    z = np.load(out)
    assert set(z.files) >= {"time_ns", "accel", "temperature", "light", "battery", "button", "segment",
                            "info"}
    ref = Block.concat(list(open_recording(p)))
    np.testing.assert_array_equal(z["time_ns"], ref.time_ns)
    np.testing.assert_array_equal(z["accel"], ref.accel_g())
    np.testing.assert_array_equal(z["temperature"], ref.temperature_per_sample())
    assert json.loads(str(z["info"]))["device_id"] == "000123"
    assert not list(tmp_path.glob(".export-*"))  # temporary columns removed


def test_export_npz_compressed_small_batches(gna, tmp_path):
    p, _, _ = gna
    out1, out2 = tmp_path / "a.npz", tmp_path / "b.npz"
    export_recording(p, out1)
    export_recording(p, out2, compress=True)
    z1, z2 = np.load(out1), np.load(out2)
    for k in ("time_ns", "accel", "light"):
        np.testing.assert_array_equal(z1[k], z2[k])


def test_export_bad_output_suffix(gna, tmp_path, capsys):
    p, _, _ = gna
    code, _, err = run_cli(["export", str(p), "-o", str(tmp_path / "o.txt")], capsys)
    assert code == 2 and "must end with .csv" in err and len(err.strip().splitlines()) == 1


def test_export_mcap_dispatch(tmp_path, capsys, monkeypatch):
    p = tmp_path / "run.mcap"
    p.write_bytes(b"\x89MCAP0\r\n" + b"\x00" * 64)
    out = tmp_path / "o.csv"
    # the MCAP exporter is called with (path, out, topics)
    calls = []
    fake = types.ModuleType("stillpoint.engine.mcap.export")
    fake.export_mcap = lambda path, o, topics: calls.append((str(path), str(o), topics)) or 5
    monkeypatch.setitem(sys.modules, "stillpoint.engine.mcap.export", fake)
    code, _, _ = run_cli(["export", str(p), "-o", str(out), "--topic", "/a", "--topic", "/b"], capsys)
    assert code == 0 and calls == [(str(p), str(out), ["/a", "/b"])]


def test_formatters():
    m = format_fixed(np.array([0.5, -0.0000004, -1.25, 12.0, np.nan]), 6)
    rows = [bytes(r[r != 0]).decode() for r in m]
    assert rows == ["0.500000", "0.000000", "-1.250000", "12.000000", ""]
    s = format_scaled(np.array([1_700_000_000_123_456_789, -5]), 9)
    assert [bytes(r[r != 0]).decode() for r in s] == ["1700000000.123456789", "-0.000000005"]
    ti = format_time(np.array([1_551_178_506_000_500_999]), "iso")
    assert bytes(ti[0]).decode() == "2019-02-26T10:55:06.000500Z"
    # the vectorised ISO formatter equals numpy's datetime64 text (1906..2096, leap years, pre-1970)
    t = np.random.default_rng(0).integers(-2 * 10**18, 4 * 10**18, 20000)
    t = np.concatenate([t, [0, -1, 951_782_400_000_000_000, 4_107_542_399_999_999_999]])
    ref = np.char.add(np.datetime_as_string(t.astype("datetime64[ns]"), unit="us").astype("S26"), b"Z")
    np.testing.assert_array_equal(format_time(t, "iso").view("S27").ravel(), ref)
    # integers: exact, no leading zeros, sign
    v = np.array([0, 7, -7, 10, 99, 100, -123456789012345678, 2**62])
    np.testing.assert_array_equal([bytes(r[r != 0]).decode() for r in format_scaled(v)],
                                  [str(int(x)) for x in v])


# ---------------------------------------------------------------------------- .cwa through the CLI
def _cwa_file(tmp_path):
    cwa = pytest.importorskip("stillpoint.drivers.cwa")
    p = tmp_path / "rec.cwa"
    w = cwa.CwaWriter(str(p), device_type="AX6", device_id=4242, session_id=7, rate_hz=100.0,
                      range_g=8, gyro_range_dps=2000)
    n = 2000
    t = T0 + np.arange(n) * 10_000_000
    rng = np.random.default_rng(0)
    w.write(t, rng.integers(-4000, 4000, (n, 3)), gyro_counts=rng.integers(-3000, 3000, (n, 3)))
    w.close()
    return p, t


def test_inspect_and_export_cwa(tmp_path, capsys):
    p, t = _cwa_file(tmp_path)
    d = inspect_recording(p)
    assert d["device_type"] == "AX6" and d["device_id"] == "4242" and d["session_id"] == 7
    assert d["samples"] == 2000 and "sectors" in d
    assert d["sample_rate_measured"] == pytest.approx(100.0, rel=1e-4)
    assert d["start_ns"] == pytest.approx(int(t[0]), abs=40_000)
    out = tmp_path / "o.csv"
    code, _, _ = run_cli(["export", str(p), "-o", str(out)], capsys)
    assert code == 0
    rows = list(csv.reader(out.open()))
    # a .cwa without --timezone: the device clock in a time_local column, never "...Z"
    assert rows[0] == ["time_local", "x", "y", "z", "gx", "gy", "gz", "temperature", "light",
                       "battery"]
    assert not rows[1][0].endswith("Z")
    assert len(rows) == 2001
    ref = Block.concat(list(open_recording(p)))
    np.testing.assert_allclose(np.array([[float(v) for v in r[4:7]] for r in rows[1:]]), ref.gyro_dps(),
                               atol=1e-5)


# ---------------------------------------------------------------------------- every real file
REAL = ["geneactiv_actfast_cmi_60hz_20pages_LF_fw0617.bin", "geneactiv_genearead_TESTfile_100hz_104pages.bin",
        "geneactiv_ggirread_testfile_85p7hz_truncated64k.bin",
        "geneactiv_romeosajina_left_ankle_20hz_truncated.bin", "geneactiv_skdh_gait_back_50hz_22pages.bin",
        "geneactiv_skdh_sample_50hz_3pages_LF_edited.bin", "geneactiv_sleeppy_test_100hz_64pages.bin",
        "ax3_ggirread_corrupt_blocks_0_13_14_142_143_144.cwa", "ax3_ggirread_testfile_100hz_145blocks.cwa",
        "ax3_openmovement_example_610_steps_fw30_nofrac.cwa",
        "ax3_oxwearables_tiny_sample_3h_with_restart.cwa.gz", "ax3_skdh_sample_200hz_490blocks.cwa",
        "ax6_ggirread_testfile_100hz_16g_gyro250dps.cwa", "ax6_skdh_sample_100hz_16g_gyro2000dps.cwa"]


@pytest.mark.parametrize("name", REAL)
def test_inspect_and_export_every_real_file(real_file, tmp_path, name):
    if name.endswith((".cwa", ".cwa.gz")):
        pytest.importorskip("stillpoint.drivers.cwa")
    p = real_file(name)
    d = inspect_recording(p)
    assert d["samples"] > 0
    if name.startswith("geneactiv"):  # the header states the zone: UTC times
        assert d["start"].endswith("Z") and d["timezone_offset_s"] is not None
    else:  # a .cwa without --timezone: the device clock, never labelled UTC
        assert d["start"] is None and d["timezone_offset_s"] is None
        assert d["start_local"][:19] == str(np.datetime64(d["start_ns"], "ns"))[:19]
    unit = "pages" if name.startswith("geneactiv") else "sectors"
    assert d[unit]["valid"] + d[unit]["skipped"] == d[unit]["total"]
    assert d["sample_rate_measured"] == pytest.approx(d["sample_rate_nominal"], rel=0.05)
    out = tmp_path / "o.npz"
    rep = export_recording(p, out)
    z = np.load(out)
    assert rep["samples"] == d["samples"] == z["time_ns"].shape[0] == z["accel"].shape[0]
    assert z["time_ns"][0] == d["start_ns"] and z["time_ns"][-1] == d["end_ns"]
    assert np.all(np.abs(z["accel"]) < 17)
    assert np.nanmin(z["temperature"]) == pytest.approx(d["temperature_range_c"][0])


def test_cli_subprocess_on_real_geneactiv(real_file, tmp_path):
    p = real_file("geneactiv_ggirread_testfile_85p7hz_truncated64k.bin")
    r = subprocess.run([sys.executable, "-m", "stillpoint.tools", "inspect", str(p), "--json"],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    d = json.loads(r.stdout)
    assert d["samples"] == 5031 and d["pages"] == {"total": 17, "valid": 17, "skipped": 0}
    assert [q["reason"] for q in d["qc"]] == ["truncated_page", "page_count_mismatch"]
    assert d["start"] == "2013-05-30T09:12:54.500000000Z"


def test_inspect_gzip_bin_and_cwa_timezone(tmp_path, gna, capsys):
    p, t, _ = gna
    gz = tmp_path / "rec.bin.gz"
    gz.write_bytes(gzip.compress(p.read_bytes()))
    d = inspect_recording(gz)
    assert d["samples"] == 3000 and d["format"] == "geneactiv" and d["start_ns"] == int(t[0])
    cp, ct = _cwa_file(tmp_path)
    a = inspect_recording(cp)
    b = inspect_recording(cp, timezone="+01:00")
    assert b["timezone_offset_s"] == 3600 and a["start_ns"] - b["start_ns"] == 3600 * 10**9
    code, _, err = run_cli(["inspect", str(cp), "--timezone", "nonsense"], capsys)
    assert code == 2 and "timezone" in err.lower()


def test_inspect_several_files_json_lines(gna, tmp_path, capsys):
    p, _, _ = gna
    bad = tmp_path / "bad.bin"
    bad.write_bytes(b"")
    code, out, err = run_cli(["inspect", "--json", str(p), str(bad), str(p)], capsys)
    assert code == 2
    rows = [json.loads(line) for line in out.splitlines()]
    assert [r["samples"] for r in rows] == [3000, 3000]
    assert err.count("\n") == 1 and str(bad) in err and "empty" in err
    code, out, err = run_cli(["inspect", str(p), str(p)], capsys)
    assert code == 0 and out.count("samples     3000") == 2
