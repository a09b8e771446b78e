"""ActiGraph .gt3x on the public files (data/real PROVENANCE.md): actfast's 60 Hz MOS file and its
asserted first sample, the NHANES legacy sample, pygt3x's legacy file against ActiLife's own CSV
export (byte for byte), and the idle-sleep on/off pair; plus damaged copies of them."""

from __future__ import annotations

import io
import zipfile

import numpy as np
import pytest

from stillpoint.drivers import RecordingError, open_recording, sniff_format
from stillpoint.drivers import gt3x as G
from stillpoint.drivers.actilife_csv import write_actilife_csv
from stillpoint.engine.core.blocks import PER_SAMPLE_IDLE_SLEEP, Block

MOS = "actigraph_actfast_mos_60hz_81s.gt3x"
NHANES = "actigraph_nhanes_neo_30hz_legacy.gt3x"
NEO = "actigraph_pygt3x_neo_30hz_legacy.gt3x"
NEO_CSV = "actigraph_pygt3x_neo_30hz_legacy.actilife.csv"
ISM_ON = "actigraph_pygt3x_tas_30hz_ism_enabled.gt3x"
ISM_OFF = "actigraph_pygt3x_tas_30hz_ism_disabled.gt3x"


def _read(path, **kw):
    with G.Gt3xReader(path, **kw) as src:
        blocks = list(src)
    return src, (Block.concat(blocks) if blocks else None)


def _iso(t_ns) -> str:
    return str(np.datetime64(int(t_ns), "ns"))


def _records(log: bytes):
    """(offset, type, time, payload) of every record, walked one by one (spec README.md 62-100)."""
    out, p = [], 0
    while p + 8 <= len(log):
        assert log[p] == 0x1E
        size = int.from_bytes(log[p + 6:p + 8], "little")
        out.append((p, log[p + 1], int.from_bytes(log[p + 2:p + 6], "little"), log[p + 8:p + 8 + size]))
        p += 9 + size
    return out


def _rezip(path, out, replace: dict):
    """A copy of a .gt3x with some members replaced (stored, as the device writes them)."""
    with zipfile.ZipFile(path) as zin, zipfile.ZipFile(out, "w", zipfile.ZIP_STORED) as zout:
        for name in zin.namelist():
            zout.writestr(name, replace.get(name, zin.read(name)))
    return out


# ---------------------------------------------------------------------- the spec's own example
def test_unpack12_matches_the_spec_example():
    # [GT3X] LogRecords/Activity.md 43-160 / [NHANES] activity.bin.md: Y X Z of three samples
    data = bytes.fromhex("00 60 08 EB D0 07 00 9E BF 00 70 08 EB F0".replace(" ", ""))
    v = G.unpack12(np.frombuffer(data, np.uint8), 3)
    assert v.tolist() == [[6, 8, -323], [7, 9, -321], [7, 8, -321]]


def test_ssp_float_code_matches_the_spec_examples():
    # [GT3X] Parameters.md 225-246: IMU_ACCEL_SCALE 2048, ACCEL_SCALE 256, IMU_TEMP_OFFSET 21
    assert G.ssp_decode(0x0C400000) == 2048.0
    assert G.ssp_decode(0x09400000) == 256.0
    assert G.ssp_decode(0x05540000) == 21.0
    assert G.ssp_decode(0) == 0.0


# ---------------------------------------------------------------------- actfast's MOS file
def test_mos_file_first_sample_and_count(real_file):
    path = real_file(MOS)
    assert sniff_format(path) == "gt3x"
    src, b = _read(path)
    info = src.info
    assert (info.device_type, info.device_id, info.firmware) == ("ActiGraph", "MOS2E17210537", "1.9.2")
    assert info.header["model"] == "wGT3XBT" and info.header["layout"] == "log.bin"
    assert info.sample_rate_nominal == 60 and info.accel_range_g == 8
    assert info.header["scale"] == 256 and info.header["scale_source"] == "info.txt Acceleration Scale"
    assert info.timezone_offset_s == -5 * 3600
    assert b.n == 4860  # actfast's test: 81 s at 60 Hz
    np.testing.assert_allclose(b.accel_g()[0], [-0.519531, -0.519531, -0.636719], atol=5e-6)
    # record times are the device clock (14:53:00 local, -05:00)
    assert _iso(b.time_ns[0]) == "2024-04-30T19:53:00.000000000"
    assert _iso(b.time_ns[-1]) == "2024-04-30T19:54:20.983333333"
    assert src.qc.segments == 1 and src.usb_connections == [1714488862]
    assert [e.reason for e in src.qc.events] == ["usb_connect"]
    assert not b.per_sample[PER_SAMPLE_IDLE_SLEEP].any()


def test_mos_file_equals_a_slow_decode_of_every_record(real_file):
    """Every sample against a per-nibble decode written from the spec's C# (Activity.md 166-236)."""
    path = real_file(MOS)
    log = zipfile.ZipFile(path).read("log.bin")
    want = []
    for _, typ, _, pl in _records(log):
        if typ != 0 or len(pl) == 1:
            continue
        nib = [(x >> s) & 0xF for x in pl for s in (4, 0)]
        for i in range(60):
            yxz = []
            for a in range(3):
                k = (3 * i + a) * 3
                v = (nib[k] << 8) | (nib[k + 1] << 4) | nib[k + 2]
                yxz.append(v - 4096 if v & 0x800 else v)
            want.append([yxz[1], yxz[0], yxz[2]])
    _, b = _read(path)
    assert b.accel.tolist() == want


# ---------------------------------------------------------------------- legacy layout
def test_nhanes_legacy_sample(real_file):
    path = real_file(NHANES)
    src, b = _read(path)
    info = src.info
    assert info.header["layout"] == "legacy" and info.header["model"] == "GT3XPlus"
    assert info.header["scale"] == 341 and info.header["scale_source"] == "serial prefix NEO"
    assert info.accel_range_g == 6
    # no TimeZone in info.txt: zone unknown, the device clock read as UTC (as a .cwa)
    assert info.header["timezone_stored_s"] is None and info.timezone_offset_s == 0
    assert b.n == 47104 * 8 // 36  # [NHANES] README.md 117
    assert _iso(b.time_ns[0]) == "2010-10-26T13:30:00.000000000"
    assert np.all(np.diff(b.time_ns) > 0)
    # independent decode of the first two samples (9 bytes: Y X Z Y X Z, 12 bits each)
    raw = zipfile.ZipFile(path).read("activity.bin")[:9]
    vals = [int(raw.hex()[i:i + 3], 16) for i in range(0, 18, 3)]
    vals = [v - 4096 if v >= 2048 else v for v in vals]
    assert b.accel[:2].tolist() == [[vals[1], vals[0], vals[2]], [vals[4], vals[3], vals[5]]]
    # lux.bin: one value per second (GT3X+ scale 1.25, < 20 -> 0)
    lux = np.frombuffer(zipfile.ZipFile(path).read("lux.bin"), "<u2").astype(float)
    exp = np.where((lux < 20) | (lux == 65535), 0, np.minimum(np.floor(lux * 1.25 + 0.5), 2500))
    assert b.light.tolist() == exp[:b.m].astype(int).tolist()


def test_neo_legacy_export_equals_actilife_byte_for_byte(real_file):
    path, ref = real_file(NEO), real_file(NEO_CSV)
    f = io.StringIO(newline="")
    with G.Gt3xReader(path) as src:
        rows = write_actilife_csv(src, f)
    assert rows == {"samples": 18004, "zero_rows": 0, "idle_rows": 0, "rows": 18004,
                    "zero_seconds_cut": 0}
    assert f.getvalue().encode() == ref.read_bytes()


def test_actilife_rounding_is_half_away_from_zero(real_file):
    """The rule the export relies on: numpy's half-to-even would write other values."""
    counts = np.arange(-2048, 2048)
    away = G.scale_round_half_away(counts, 256.0)
    even = np.round(counts / 256.0 * 1000).astype(int)
    assert (away != even).any()  # ties (k/256 = m + 0.5 thousandths) exist at 256 LSB/g
    assert G.scale_round_half_away(np.array([16, -16]), 256.0).tolist() == [63, -63]  # 0.0625


def test_neo_legacy_matches_actilife_column_means(real_file):
    path, ref = real_file(NEO), real_file(NEO_CSV)
    want = np.loadtxt(ref, delimiter=",", skiprows=11)
    _, b = _read(path)
    np.testing.assert_allclose(b.accel_g(), want, atol=0.0005 + 1e-12)
    assert _iso(b.time_ns[0]) == "2021-12-20T17:55:00.000000000"  # 11:55:00 at -06:00


# ---------------------------------------------------------------------- idle sleep
def test_idle_sleep_pair(real_file):
    on, b_on = _read(real_file(ISM_ON))
    off, b_off = _read(real_file(ISM_OFF))
    assert on.info.header["idle_sleep_enabled"] is True
    assert off.info.header["idle_sleep_enabled"] is False
    # both cover the same 300 s (as pygt3x's test: same index); 73 s of records in the enabled one
    assert b_on.n == b_off.n == 300 * 30
    assert np.array_equal(b_on.time_ns, b_off.time_ns)
    assert on.qc.valid == 73 and off.qc.valid == 300
    # idle periods from the EVENT records: 15:57:24-15:58:32, 15:58:57-15:59:35, 15:59:59-end
    assert on.idle_periods == [(1616169444, 68), (1616169537, 38), (1616169599, 121)]
    assert on.idle_sleep_s == 227 and off.idle_sleep_s == 0
    idle = b_on.per_sample[PER_SAMPLE_IDLE_SLEEP].astype(bool)
    assert idle.sum() == 227 * 30 and not b_off.per_sample[PER_SAMPLE_IDLE_SLEEP].any()
    # every idle run repeats the last sample before it
    starts = np.flatnonzero(np.diff(np.r_[0, idle.astype(int)]) == 1)
    for s in starts:
        e = s + np.argmin(idle[s:]) if not idle[s:].all() else b_on.n
        assert (b_on.accel[s:e] == b_on.accel[s - 1]).all()
    assert on.qc.segments == 1


def test_idle_sleep_unfilled_gives_segments(real_file):
    src, b = _read(real_file(ISM_ON), fill_idle_sleep=False)
    assert b is None or b.n == 73 * 30
    assert src.qc.segments == 3  # the two closed idle periods break the stream
    assert src.idle_sleep_s == 227


def test_actilife_gap_rules_on_the_idle_sleep_file(real_file):
    f = io.StringIO(newline="")
    with G.Gt3xReader(real_file(ISM_ON)) as src:
        rows = write_actilife_csv(src, f)
    # 15:57:00 to the download time 16:12:12: 912 s at 30 Hz; idle repeated, the rest zeros
    assert rows == {"samples": 9000, "zero_rows": (912 - 300) * 30, "idle_rows": 227 * 30,
                    "rows": 912 * 30, "zero_seconds_cut": 0}
    lines = f.getvalue().split("\r\n")
    assert lines[10] == "Accelerometer X,Accelerometer Y,Accelerometer Z"
    assert lines[1] == "Serial Number: TAS1E42150038" and lines[5] == "Download Time 16:12:12"
    data = lines[11:-1]
    assert len(data) == 912 * 30 and set(data[300 * 30:]) == {"0,0,0"}


# ---------------------------------------------------------------------- damage
def test_bad_checksum_and_junk_resync(real_file, tmp_path):
    path = real_file(MOS)
    log = bytearray(zipfile.ZipFile(path).read("log.bin"))
    acts = [r for r in _records(bytes(log)) if r[1] == 0 and len(r[3]) > 1]
    log[acts[10][0] + 20] ^= 0xFF  # a payload byte of the 11th second
    junk = acts[40][0]
    log[junk:junk] = b"\x01\x02\x03garbage"  # bytes that are not a record before the 41st
    p = _rezip(path, tmp_path / "damaged.gt3x", {"log.bin": bytes(log)})
    src, b = _read(p)
    reasons = [e.reason for e in src.qc.events]
    assert "checksum" in reasons and "resync" in reasons and "time_gap" in reasons
    assert b.n == 80 * 60 and src.qc.skipped == 1 and src.qc.segments == 2
    _, good = _read(path)
    keep = np.r_[0:600, 660:4860]
    assert np.array_equal(b.accel, good.accel[keep])


def test_axis_turn_of_firmware_1_6_0_is_undone(real_file, tmp_path):
    path = real_file(MOS)
    info = zipfile.ZipFile(path).read("info.txt").replace(b"Firmware: 1.9.2", b"Firmware: 1.6.0")
    src, b = _read(_rezip(path, tmp_path / "fw160.gt3x", {"info.txt": info}))
    _, good = _read(path)
    assert src.info.header["axis_swap_fixed"]
    assert np.array_equal(b.accel[:, 0], good.accel[:, 1])
    assert np.array_equal(b.accel[:, 1], -good.accel[:, 0])


def test_scale_falls_back_to_parameters_then_serial(real_file, tmp_path):
    path = real_file(MOS)
    info = zipfile.ZipFile(path).read("info.txt").replace(b"Acceleration Scale: 256.0\r\n", b"")
    src, _ = _read(_rezip(path, tmp_path / "noscale.gt3x", {"info.txt": info}))
    assert src.info.header["scale"] == 256 and src.info.header["scale_source"] == "PARAMETERS ACCEL_SCALE"


@pytest.mark.parametrize("cut", [100, 5000, 20000, 23700, 24000, 24900])
def test_truncated_zip_recovers_records_or_says_why(real_file, tmp_path, cut):
    """A download cut short loses the zip's central directory: the members are then read from
    their local headers. Cut before info.txt (written after log.bin): a one-line typed error."""
    p = tmp_path / "cut.gt3x"
    p.write_bytes(real_file(MOS).read_bytes()[:cut])
    if cut < 23732:  # before info.txt's local header (zip listing); a part of info.txt is enough
        with pytest.raises(RecordingError, match="no info.txt") as e:
            _read(p)
        assert str(p) in str(e.value) and "\n" not in str(e.value)
        return
    src, b = _read(p)
    assert src.info.header["zip_recovered"] and b.n == 4860


def test_zip_bomb_is_refused(tmp_path, monkeypatch):
    monkeypatch.setattr(G, "BOMB_MIN_BYTES", 1 << 20)
    p = tmp_path / "bomb.gt3x"
    with zipfile.ZipFile(p, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("info.txt", "Serial Number: MOS2E17210537\r\nSample Rate: 30\r\n")
        z.writestr("log.bin", b"\0" * (8 << 20))
    with pytest.raises(RecordingError, match="zip bomb"):
        _read(p)


def test_not_a_gt3x_zip(tmp_path):
    p = tmp_path / "other.gt3x"
    with zipfile.ZipFile(p, "w") as z:
        z.writestr("readme.txt", "hello")
    with pytest.raises(RecordingError, match="no info.txt"):
        open_recording(p)


# ---------------------------------------------------------------------- command line
def test_cli_export_actilife_and_inspect(real_file, tmp_path, capsys):
    from stillpoint.tools.cli import main
    out = tmp_path / "neo.csv"
    assert main(["export", str(real_file(NEO)), "-o", str(out), "--actilife"]) == 0
    assert out.read_bytes() == real_file(NEO_CSV).read_bytes()
    capsys.readouterr()
    assert main(["inspect", "--json", str(real_file(ISM_ON))]) == 0
    import json
    d = json.loads(capsys.readouterr().out)
    assert d["format"] == "gt3x" and d["timezone"] == "-05:00" and d["samples"] == 9000
    ag = d["actigraph"]
    assert (ag["model"], ag["layout"], ag["scale_lsb_per_g"], ag["timezone_stored"]) == \
        ("Link", "log.bin", 256.0, "-05:00")
    assert ag["idle_sleep_enabled"] is True and ag["idle_sleep_s"] == 227
    assert "idle_sleep" in d["channels"]
    # --actilife on another format, and a damaged .gt3x: one line, exit 2
    bad = tmp_path / "bad.gt3x"
    bad.write_bytes(b"PK\x03\x04" + b"\0" * 40)
    assert main(["inspect", str(bad)]) == 2
    err = capsys.readouterr().err.strip()
    assert str(bad) in err and "\n" not in err
    assert main(["export", str(real_file("ax3_ggirread_testfile_100hz_145blocks.cwa")), "-o",
                 str(tmp_path / "x.csv"), "--actilife"]) == 2
