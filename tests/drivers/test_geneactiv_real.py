"""Conformance on the real GENEActiv recordings (facts from PROVENANCE.md and the spec, plus an
independent slow decode of the first/last page written here with int(hex, 16))."""

from __future__ import annotations

import datetime as dt

import numpy as np
import pytest

from stillpoint.drivers import UnsupportedFormatError, open_recording, sniff_format
from stillpoint.drivers.geneactiv import GeneactivReader, read_header
from stillpoint.engine.core.blocks import PER_SAMPLE_LIGHT_RAW, Block

# name: (serial, rate, samples, first sample UTC, last sample UTC, tz seconds, temp min, temp max,
#        pages in file, header Number of Pages, firmware)
FILES = {
    "geneactiv_ggirread_testfile_85p7hz_truncated64k.bin":
        ("012967", 600 / 7, 16 * 300 + 231, "2013-05-30T09:12:54.500", "2013-05-30T09:13:53.183333333",
         3600, 21.5, 23.1, 17, 222048, "Ver1.30 date 05Aug11"),
    "geneactiv_genearead_TESTfile_100hz_104pages.bin":
        ("011073", 100.0, 31200, "2012-05-23T15:47:50.000", "2012-05-23T15:53:01.990",
         3600, 24.7, 26.3, 104, 104, "Ver 1.0 date 20dec10"),
    "geneactiv_sleeppy_test_100hz_64pages.bin":
        ("035645", 100.0, 19200, "2018-08-27T13:32:38.000", "2018-08-27T13:35:49.990",
         -14400, 23.1, 24.7, 64, 64, "Ver4.08a date14Jul14"),
    "geneactiv_skdh_sample_50hz_3pages_LF_edited.bin":
        ("051386", 50.0, 900, "2019-05-21T20:16:43.500", "2019-05-21T20:17:01.980",
         -14400, 28.1, 29.1, 3, 3, "Ver4.08a date14Jul14"),
    "geneactiv_skdh_gait_back_50hz_22pages.bin":
        ("048877", 50.0, 6600, "2020-03-05T19:27:42.500", "2020-03-05T19:29:54.980",
         -18000, 30.6, 35.4, 22, 22, "Ver4.08a date14Jul14"),
    "geneactiv_actfast_cmi_60hz_20pages_LF_fw0617.bin":
        ("101806", 60.0, 6000, "2024-04-30T20:13:30.000", "2024-04-30T20:15:09.983333333",
         -18000, 31.2, 35.8, 20, 20, "Ver06.17 15June23"),
    "geneactiv_romeosajina_left_ankle_20hz_truncated.bin":
        ("052192", 20.0, 3900, "2020-01-30T08:17:11.000", "2020-01-30T08:20:25.950",
         3600, 18.9, 21.0, 13, 480, "Ver4.08a date14Jul14"),
}


def iso_ns(s: str) -> int:
    base, _, frac = s.partition(".")
    t = dt.datetime.fromisoformat(base).replace(tzinfo=dt.timezone.utc)
    return int(t.timestamp()) * 10**9 + int(frac.ljust(9, "0"))


def reference_page(path, which):
    """Slow independent decode of one page's first data line: list of (x, y, z, light) raw."""
    lines = path.read_bytes().replace(b"\r\n", b"\n").split(b"\n")
    marks = [i for i, ln in enumerate(lines) if ln == b"Recorded Data"]
    hexline = lines[marks[which] + 9].decode()
    out = []
    for s in range(0, len(hexline) - 11, 12):
        v = int(hexline[s:s + 12], 16)
        fields = [(v >> sh) & 0xFFF for sh in (36, 24, 12)]
        out.append(tuple(f - 4096 if f >= 2048 else f for f in fields) + (((v & 0xFFF) >> 2),))
    return out


@pytest.fixture(scope="module")
def decoded(real_data_dir):
    out = {}
    for name in FILES:
        p = real_data_dir / name
        if not p.is_file():
            pytest.fail(f"real recording {name} missing from {real_data_dir}")
        r = GeneactivReader(p)
        blocks = list(r)
        out[name] = (r, blocks, Block.concat(blocks))
    return out


@pytest.mark.parametrize("name", sorted(FILES))
def test_facts(real_file, decoded, name):
    serial, rate, n, first, last, tz, tmin, tmax, pages, hdr_pages, fw = FILES[name]
    r, blocks, b = decoded[name]
    info = r.info
    assert info.device_type == "GENEActiv"
    assert info.device_id == serial
    assert info.firmware == fw
    assert info.sample_rate_nominal == rate
    assert info.timezone_offset_s == tz
    assert info.accel_range_g == 8.0
    assert b.n == n
    assert int(b.time_ns[0]) == iso_ns(first)
    assert abs(int(b.time_ns[-1]) - iso_ns(last)) <= 1  # floor to whole ns
    assert np.nanmin(b.temperature_c) == tmin and np.nanmax(b.temperature_c) == tmax
    assert r.qc.total == pages
    assert info.header["number_of_pages"] == hdr_pages
    mismatch = [e for e in r.qc.events if e.reason == "page_count_mismatch"]
    assert len(mismatch) == (hdr_pages != pages)
    assert np.all(np.diff(b.time_ns) > 0)
    assert np.all(np.isfinite(b.battery_v)) and np.all((b.battery_v > 3.0) & (b.battery_v < 4.5))


@pytest.mark.parametrize("name", sorted(FILES))
def test_first_and_last_page_match_independent_decode(real_file, decoded, name):
    r, _, b = decoded[name]
    gains = np.array(r.info.header["gains"], float)
    offsets = np.array(r.info.header["offsets"], float)
    for which, sl in ((0, slice(0, 300)), (-1, slice(int(b.unit_start[-1]), b.n))):
        ref = np.array(reference_page(real_file(name), which))
        np.testing.assert_array_equal(b.accel[sl], ref[:, :3])
        np.testing.assert_array_equal(b.per_sample[PER_SAMPLE_LIGHT_RAW][sl], ref[:, 3])
        np.testing.assert_allclose(b.accel_g()[sl], (ref[:, :3] * 100.0 - offsets) / gains, atol=1e-12)


def test_ggirread_testfile_values_from_the_spec(decoded):
    r, _, b = decoded["geneactiv_ggirread_testfile_85p7hz_truncated64k.bin"]
    g = b.accel_g()
    np.testing.assert_allclose(g[0], [0.74052, 0.01407, -0.64390], atol=5e-6)
    assert b.accel[0].tolist() == [196, -3, -195]
    assert g[299, 2] == pytest.approx(-0.80836401, abs=5e-9)  # spec §5, exact double arithmetic
    # GGIRread's own test asserts -0.8083640337 (single-precision arithmetic: 2.7e-8 away)
    assert g[299, 2] == pytest.approx(-0.8083640337, abs=1e-7)
    lux = b.per_sample[PER_SAMPLE_LIGHT_RAW][0] * r.info.header["lux"] / r.info.header["volts"]
    assert lux == pytest.approx(2.6667, abs=1e-4)
    # pages 3.5 s apart: the true rate is 600/7 Hz, never 85.7
    assert np.all(np.diff(b.time_ns[b.unit_start]) == 3_500_000_000)


def test_truncated_file_qc(decoded):
    r, _, b = decoded["geneactiv_ggirread_testfile_85p7hz_truncated64k.bin"]
    reasons = [(e.index, e.reason) for e in r.qc.events]
    assert reasons == [(16, "truncated_page"), (17, "page_count_mismatch")]
    ev = r.qc.events[0]
    assert "231 of 300" in ev.detail and "2781 of 3600" in ev.detail
    assert (r.qc.total, r.qc.valid, r.qc.skipped, r.qc.segments) == (17, 17, 0, 1)
    assert b.m == 17 and b.n - b.unit_start[-1] == 231
    assert "222048" in r.qc.events[1].detail


def test_romeosajina_page_count_mismatch(decoded):
    r, _, _ = decoded["geneactiv_romeosajina_left_ankle_20hz_truncated.bin"]
    assert [(e.index, e.reason) for e in r.qc.events] == [(13, "page_count_mismatch")]
    assert r.info.header["clock_drift_s"] == pytest.approx(0.283)  # "(device clock drift 0,283s)"


@pytest.mark.parametrize("name", ["geneactiv_skdh_sample_50hz_3pages_LF_edited.bin",
                                  "geneactiv_skdh_gait_back_50hz_22pages.bin"])
def test_first_page_6p5s_step_is_a_time_jump_not_a_slow_page(decoded, name):
    """Both 50 Hz Ver4.08a files have 6.5 s between pages 0 and 1 (6.0 s elsewhere). Interpolating
    would put page 0 at 46.2 Hz; we keep 50 Hz and start a new segment at page 1."""
    r, blocks, b = decoded[name]
    ev = [e for e in r.qc.events if e.reason == "time_jump"]
    assert [e.index for e in ev] == [1]
    assert r.qc.segments == 2 and [bl.segment for bl in blocks] == [0, 1]
    assert blocks[0].n == 300
    d = np.diff(blocks[0].time_ns)
    assert np.all(d == 20_000_000)
    assert blocks[1].time_ns[0] - blocks[0].time_ns[-1] == 520_000_000


def test_skdh_edited_temperatures_and_lf(real_file, decoded):
    name = "geneactiv_skdh_sample_50hz_3pages_LF_edited.bin"
    assert b"\r\n" not in real_file(name).read_bytes()
    _, _, b = decoded[name]
    assert b.temperature_c.tolist() == [28.2, 28.1, 29.1]


def test_invalid_start_time_is_tolerated(decoded):
    r, _, b = decoded["geneactiv_genearead_TESTfile_100hz_104pages.bin"]
    assert r.info.header["start_time_ns"] is None
    assert any("Start Time" in w for w in r.info.header["warnings"])
    assert r.info.metadata["Subject Notes"] == "Some sample activities"
    assert r.info.metadata["Device Location Code"] == "left wrist"
    assert r.qc.events == []


def test_sleeppy_nul_padding_is_stripped(real_file):
    name = "geneactiv_sleeppy_test_100hz_64pages.bin"
    assert b"\x00" in real_file(name).read_bytes()[:3000]
    info = read_header(real_file(name))
    for k, v in info.header.items():
        if isinstance(v, str):
            assert "\x00" not in v and v == v.strip(), k
    assert "Config Operator ID" not in info.metadata  # all NULs = empty
    assert info.metadata["Study Centre"] == "001"
    assert info.header["clock_drift_s"] == pytest.approx(-12.345)


def test_actfast_newest_firmware(decoded):
    r, _, _ = decoded["geneactiv_actfast_cmi_60hz_20pages_LF_fw0617.bin"]
    assert r.info.header["model"] == "1.2"
    assert r.info.header["Light Meter Range"] == "0 to 20000"


def test_original_genea_file_is_rejected(real_file):
    p = real_file("NOT_geneactiv_original_GENEA_device_ggirread.bin")
    with pytest.raises(UnsupportedFormatError, match="original GENEA") as e:
        GeneactivReader(p)
    assert str(p) in str(e.value)
    with pytest.raises(UnsupportedFormatError, match="original GENEA"):
        read_header(p)
    with pytest.raises(UnsupportedFormatError, match="original GENEA"):
        sniff_format(p)


def test_open_recording_dispatches(real_file):
    src = open_recording(real_file("geneactiv_sleeppy_test_100hz_64pages.bin"))
    assert isinstance(src, GeneactivReader)
    src.close()
