"""Conformance on the real .cwa recordings in STILLPOINT_REAL_DATA (facts: PROVENANCE.md,
cwa-format.md §7.4/§11, and values recomputed here from the raw bytes with ``struct``).

Note on first-sample times: PROVENANCE.md quotes them the way OmApi computes them (anchor minus
idx / *nominal* rate). We extrapolate before a segment's first anchor with the *measured* slope
of the first two anchors (cwa-format.md §7.2), so our first samples are a few ms earlier; the
anchor samples themselves match the spec's worked values exactly.
"""

from __future__ import annotations

import calendar
import struct

import numpy as np
import pytest

from stillpoint.drivers.cwa import read_header

from cwa_helpers import qc_reasons, read_all

AX3 = "ax3_ggirread_testfile_100hz_145blocks.cwa"
AX3_BAD = "ax3_ggirread_corrupt_blocks_0_13_14_142_143_144.cwa"
AX6 = "ax6_ggirread_testfile_100hz_16g_gyro250dps.cwa"
AX3_SKDH = "ax3_skdh_sample_200hz_490blocks.cwa"
AX6_SKDH = "ax6_skdh_sample_100hz_16g_gyro2000dps.cwa"
FW30 = "ax3_openmovement_example_610_steps_fw30_nofrac.cwa"
OXF = "ax3_oxwearables_tiny_sample_3h_with_restart.cwa.gz"


def ns(text: str) -> int:
    """'2019-02-26 10:55:07.25049' (naive = UTC) -> int ns."""
    return int(np.datetime64(text.replace(" ", "T"), "ns").astype(np.int64))


def raw_anchor(path, k):
    """Independent §7.2 anchor of data sector k from the raw bytes: (global index, t seconds)."""
    with open(path, "rb") as f:
        f.seek(1024 + 512 * k)
        s = f.read(512)
    frac, ts, off, cnt = struct.unpack_from("<H", s, 4)[0], struct.unpack_from("<I", s, 14)[0], \
        struct.unpack_from("<h", s, 26)[0], struct.unpack_from("<H", s, 28)[0]
    y, mo, d = 2000 + (ts >> 26), (ts >> 22) & 15, (ts >> 17) & 31
    h, mi, se = (ts >> 12) & 31, (ts >> 6) & 63, ts & 63
    t = calendar.timegm((y, mo, d, h, mi, se))
    rate = 3200 >> (15 - (s[24] & 15))
    if frac & 0x8000:
        f16 = (frac & 0x7FFF) << 1
        return off + (f16 * rate) // 65536, t + f16 / 65536, cnt
    return off, float(t), cnt


def first_sample_expected(path, k0=0):
    """Time of the first sample of a segment starting at sector k0 (two-anchor extrapolation)."""
    g0, t0, c0 = raw_anchor(path, k0)
    g1, t1, _ = raw_anchor(path, k0 + 1)
    g1 += c0
    return t0 - g0 * (t1 - t0) / (g1 - g0)


def test_ax3_ggirread(real_file):
    p = real_file(AX3)
    r = read_all(p)
    rd, info = r["reader"], r["reader"].info
    assert (info.device_type, info.device_id, info.session_id, info.firmware) == ("AX3", "39434", 26, "44")
    assert info.sample_rate_nominal == 100.0 and info.accel_range_g == 8.0 and info.gyro_range_dps is None
    assert info.metadata == {"Body Location": "right wrist", "Subject Code": "26"}
    assert info.header["annotation"] == "_p=right+wrist&_sc=26"
    assert info.header["logging_start"] == "2019-02-26T10:55:00Z"
    assert info.header["logging_end"] == "2019-02-26T10:58:00Z"
    assert info.header["hardware_type"] == 0x00 and info.header["rate_code"] == 0x4A
    assert (rd.qc.total, rd.qc.valid, rd.qc.skipped, rd.qc.segments) == (145, 145, 0, 1)
    assert rd.qc.events == []
    assert r["n"] == 17_400
    g = r["accel"][:2] / r["blocks"][0].accel_counts_per_g
    np.testing.assert_allclose(g, [[0.328, 0.984, 0.203], [0.828, -0.359, -0.375]], atol=0.001)
    # spec §7.4 worked anchors: sector 0 idx 125 at :07.25049, sector 1 idx 130 at :08.51514
    assert abs(r["time"][125] - ns("2019-02-26 10:55:07.250488")) < 1000
    assert abs(r["time"][250] - ns("2019-02-26 10:55:08.515137")) < 1000
    assert abs(r["time"][0] / 1e9 - first_sample_expected(p)) < 1e-6
    assert abs(r["time"][0] - ns("2019-02-26 10:55:06.0005")) < 20e6  # OmApi (nominal) within 20 ms
    assert r["temperature_raw"].min() == 258 and r["temperature_raw"].max() == 261
    assert r["temperature_c"][0] == pytest.approx(25.5859375)
    assert r["battery_v"][0] == pytest.approx((190 + 512) * 6 / 1024)
    assert r["light"][0] == 283 and r["events"][0] == 0x01
    np.testing.assert_array_equal(r["unit_sequence"], np.arange(145))
    rate = (r["n"] - 1) / ((r["time"][-1] - r["time"][0]) / 1e9)
    assert rate == pytest.approx(98.86, abs=0.01)  # spec §7.2: 98.86 Hz effective


def test_ax3_corrupt_blocks(real_file):
    r = read_all(real_file(AX3_BAD))
    rd = r["reader"]
    assert [i for i, why in qc_reasons(rd) if why == "checksum"] == [0, 13, 14, 142, 143, 144]
    assert [(i, why) for i, why in qc_reasons(rd) if why != "checksum"] == [(15, "sequence_gap")]
    assert "12 -> 15" in [e.detail for e in rd.qc.events if e.reason == "sequence_gap"][0]
    assert all(e.samples == 120 for e in rd.qc.events if e.reason == "checksum")
    assert (rd.qc.total, rd.qc.valid, rd.qc.skipped, rd.qc.segments) == (145, 139, 6, 2)
    # each event carries the data time next to it: a skipped sector -> last valid sample before it
    times = {(e.index, e.reason): e.time_ns for e in rd.qc.events}
    seg0_end = int(r["time"][r["segment"] == 0][-1])
    assert times[(13, "checksum")] == times[(14, "checksum")] == seg0_end
    assert times[(144, "checksum")] == int(r["time"][-1])
    assert r["n"] == 16_680 and r["unit_index"][-1] == 141
    assert abs(r["time"][0] - ns("2019-02-26 10:55:07.2151")) < 20e6
    # the valid sectors hold exactly the clean file's samples; interior times are identical
    clean = read_all(real_file(AX3))
    valid = np.setdiff1d(np.arange(145), [0, 13, 14, 142, 143, 144])
    rows = (valid[:, None] * 120 + np.arange(120)).reshape(-1)
    np.testing.assert_array_equal(r["accel"], clean["accel"][rows])
    interior = np.isin(np.repeat(valid, 120), np.r_[3:11, 17:140])
    np.testing.assert_array_equal(r["time"][interior], clean["time"][rows][interior])


def test_ax6_ggirread(real_file):
    p = real_file(AX6)
    r = read_all(p)
    rd, info = r["reader"], r["reader"].info
    assert (info.device_type, info.device_id, info.session_id, info.firmware) == ("AX6", "6011834", 993, "54")
    assert info.header["upper_device_id"] == 0x005B and info.header["device_id_low"] == 48058
    assert info.header["sensor_config"] == 0x05 and info.gyro_range_dps == 250.0
    assert info.accel_range_g == 16.0 and info.channels == (
        "accel_x", "accel_y", "accel_z", "gyro_x", "gyro_y", "gyro_z")
    assert info.metadata == {"Subject Code": "993", "Subject Notes": "test"}
    assert r["n"] == 11_320 and rd.qc.valid == 283 and rd.qc.segments == 1
    b = r["blocks"][0]
    np.testing.assert_array_equal(b.accel_counts_per_g, [2048] * 3)
    assert b.gyro_dps_per_count == 250 / 32768
    assert r["temperature_raw"].min() == 263 and r["temperature_raw"].max() == 267
    vb = r["battery_v"] * 1024 / 6 - 512
    assert vb.min() == 172 and vb.max() == 174
    # §7.4: sector 0 anchor idx 40 at 21:04:07.09979; sector 1 idx 40 (-> 80) at :07.50372
    assert abs(r["time"][40] - ns("2019-12-23 21:04:07.099792")) < 1000
    assert abs(r["time"][80] - ns("2019-12-23 21:04:07.503723")) < 1000
    assert abs(r["time"][0] / 1e9 - first_sample_expected(p)) < 1e-6
    # fw 54 < 56: the start-of-recording accel/gyro swap is flagged, not "fixed"
    swap = [e for e in rd.qc.events if e.reason == "axis_swap"]
    assert len(swap) == 1 and swap[0].index == 0 and "0..25" in swap[0].detail
    assert np.linalg.norm(r["gyro"][:40].mean(0)) / 2048 == pytest.approx(1.01, abs=0.02)
    assert np.linalg.norm(r["accel"][249 * 40:250 * 40].mean(0)) / 2048 == pytest.approx(1.01, abs=0.02)


def test_ax6_skdh_negative_offsets(real_file):
    p = real_file(AX6_SKDH)
    from stillpoint.drivers.cwa import read_sector
    assert int(read_sector(p, 0)["timestamp_offset"][0]) == -30
    r = read_all(p)
    info = r["reader"].info
    assert (info.device_id, info.session_id, info.firmware, info.gyro_range_dps) == ("6011802", 0, "53", 2000.0)
    assert info.header["logging_start"] == "always"
    assert r["n"] == 10_360 and r["reader"].qc.valid == 259
    assert r["blocks"][0].gyro_dps_per_count == 2000 / 32768
    assert abs(r["time"][0] / 1e9 - first_sample_expected(p)) < 1e-6
    assert abs(r["time"][0] - ns("2019-10-29 09:03:06.3080")) < 20e6
    assert (np.diff(r["time"]) > 0).all()
    # every sector's anchor sample sits exactly at its anchor time
    for k in (0, 5, 100, 258):
        g, t, _ = raw_anchor(p, k)
        j = 40 * k + g
        if 0 <= j < r["n"]:
            assert abs(r["time"][j] / 1e9 - t) < 1e-6


def test_ax3_skdh_200hz(real_file):
    r = read_all(real_file(AX3_SKDH))
    info = r["reader"].info
    assert (info.device_id, info.session_id, info.firmware) == ("51888", 1020030004, "45")
    assert info.sample_rate_nominal == 200.0 and info.accel_range_g == 8.0
    assert info.header["logging_start"] == "never" and info.header["logging_end"] == "never"
    assert info.metadata == {}
    assert r["n"] == 58_800 and r["reader"].qc.events == []
    assert abs(r["time"][0] - ns("2020-02-12 09:03:37.4818")) < 20e6
    assert r["temperature_raw"].min() == 261 and r["temperature_raw"].max() == 269


def test_fw30_without_fractional_timestamps(real_file):
    p = real_file(FW30)
    with open(p, "rb") as f:
        f.seek(1024 + 4)
        assert struct.unpack("<H", f.read(2))[0] == 0x0731  # device id, bit 15 clear
    r = read_all(p)
    info = r["reader"].info
    assert (info.device_id, info.firmware) == ("1841", "30")
    assert info.metadata == {"Setup Operator": "Kim"}
    assert r["n"] == 71_400 and r["reader"].qc.valid == 595 and r["reader"].qc.events == []
    assert abs(r["time"][0] - ns("2012-03-27 11:14:57.50")) < 20e6
    # without a fraction the anchor is the whole second at sample timestampOffset
    g, t, _ = raw_anchor(p, 10)
    assert r["time"][1200 + g] == int(t) * 10**9


def test_oxford_restart_gz(real_file):
    r = read_all(real_file(OXF), batch_sectors=1000)
    rd = r["reader"]
    assert rd.info.device_id == "43923" and rd.info.firmware == "46"
    assert (rd.qc.total, rd.qc.valid, rd.qc.segments) == (8515, 8515, 2)
    assert qc_reasons(rd) == [(7740, "restart")]
    assert r["n"] == 1_021_800
    seg = r["segment"]
    assert (seg[:7740 * 120] == 0).all() and (seg[7740 * 120:] == 1).all()
    assert r["unit_sequence"][7739] == 7739 and r["unit_sequence"][7740] == 0
    t = r["time"]
    jump = (t[7740 * 120] - t[7740 * 120 - 1]) / 1e9
    assert 240 < jump < 246  # about 4 min 4 s between the runs
    assert abs(t[0] - ns("2023-06-08 12:21:04.5143")) < 50e6
    for s in (0, 1):
        ts = t[seg == s]
        assert (ts.shape[0] - 1) / ((ts[-1] - ts[0]) / 1e9) == pytest.approx(97.6, abs=0.1)
    assert r["temperature_raw"].min() == 263 and r["temperature_raw"].max() == 289


def test_read_header_is_header_only(real_file):
    info = read_header(real_file(AX6), timezone="+01:00")
    assert info.device_type == "AX6" and info.timezone_offset_s == 3600
    assert info.header["logging_start"] == "2019-12-23T20:04:00Z"  # device clock 21:04 at UTC+1


@pytest.mark.parametrize("name", [AX3, AX3_BAD, AX6, AX3_SKDH, AX6_SKDH, FW30])
def test_batch_invariance_on_real_files(real_file, name):
    p = real_file(name)
    ref = read_all(p)
    for batch in (1, 13):
        got = read_all(p, batch_sectors=batch)
        for k in ("time", "accel", "unit_index", "temperature_raw", "light", "battery_v", "events"):
            np.testing.assert_array_equal(got[k], ref[k], err_msg=k)
        assert qc_reasons(got["reader"]) == qc_reasons(ref["reader"])


def test_header_quick_span(real_file):
    """read_header looks at the first/last 16 sectors only (OmApi-style) for the data span."""
    h = read_header(real_file(AX3)).header
    assert h["data_sectors"] == 145
    assert h["first_sector_time"].startswith("2019-02-26T10:55:07.2504")  # spec §7.4 anchor
    g, t, _ = raw_anchor(real_file(AX3_BAD), 141)  # last valid sector of the corrupt file
    hb = read_header(real_file(AX3_BAD)).header
    assert abs(ns(hb["last_sector_time"].rstrip("Z")) / 1e9 - t) < 1e-6
    assert read_header(real_file(OXF)).header["last_sector_time"] is None  # gzip: no tail seek
