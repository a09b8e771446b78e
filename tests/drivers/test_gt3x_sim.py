"""ActiGraph .gt3x written by the project's writer (drivers/gt3x_writer.py) and the simulator, read
back and taken through the engine: idle sleep out of the calibration, in the epoch table, in
stillpoint.read, and kept by the MCAP log (tables made from the log equal the run's)."""

from __future__ import annotations

import gzip
import zipfile

import numpy as np
import pytest

from stillpoint.drivers import open_recording
from stillpoint.drivers.gt3x import Gt3xReader, unpack12
from stillpoint.drivers.gt3x_writer import Gt3xWriter, pack12, record_bytes
from stillpoint.engine.core.blocks import PER_SAMPLE_IDLE_SLEEP, Block
from stillpoint.engine.operators.windows import WindowFeaturesOperator

RATE = 30
T0 = 1_700_000_000


def _signal(seconds: int, moving: list, seed: int = 2) -> np.ndarray:
    """Counts at rest (z = 1 g) with noise of +-20 counts in the ``moving`` [a, b) seconds."""
    rng = np.random.default_rng(seed)
    c = np.zeros((seconds * RATE, 3), np.int64) + [0, 0, 256]
    for a, b in moving:
        c[a * RATE:b * RATE] += rng.integers(-20, 20, ((b - a) * RATE, 3))
    return c


def _write(path, counts, tz=3600, **kw):
    t = np.int64(T0) * 10**9 + np.arange(counts.shape[0]) * 10**9 // RATE
    w = Gt3xWriter(path, rate_hz=RATE, timezone_s=tz, **kw)
    for a in range(0, counts.shape[0], 1000):  # several writes: seconds cut between them
        w.write(t[a:a + 1000], counts[a:a + 1000])
    w.close()
    return t, w


def _read(path):
    with Gt3xReader(path) as src:
        b = Block.concat(list(src))
    return src, b


def test_pack12_is_the_readers_inverse():
    c = np.random.default_rng(1).integers(-2048, 2048, (5, 31, 3))
    assert np.array_equal(unpack12(pack12(c), 31)[..., [1, 0, 2]], c)


def test_record_checksum_is_ones_complement_xor():
    # [GT3X] LogRecords/Metadata.md 14-22, 63-65: this record's checksum byte is 0xF8
    payload = (b'{"MetadataType":"Bio","SubjectName":"CLE2A14151617","Race":"","Limb":"","Side":"",'
               b'"Dominance":"","Parsed":false,"JSON":null}')
    r = record_bytes(6, 1421142129, payload)
    assert r[:8].hex() == "1e0671e8b4547c00" and r[-1] == 0xF8


def test_writer_round_trip_with_idle_sleep(tmp_path):
    counts = _signal(400, [(0, 100), (200, 250)])
    t, w = _write(tmp_path / "w.gt3x", counts)
    src, b = _read(tmp_path / "w.gt3x")
    assert src.info.timezone_offset_s == 3600 and src.info.header["idle_sleep_enabled"] is True
    assert b.n == counts.shape[0] and np.array_equal(b.time_ns, t)
    idle = b.per_sample[PER_SAMPLE_IDLE_SLEEP].astype(bool)
    # 10 still seconds, then asleep until it moves (or the recording ends)
    assert src.idle_periods == [(T0 + 3600 + 110, 90), (T0 + 3600 + 260, 140)]
    assert w.idle_seconds == idle.sum() // RATE == 230
    assert np.array_equal(b.accel[~idle], counts[~idle])
    assert (np.abs(b.accel[idle] - counts[idle]) <= 10).all()  # the still signal, repeated
    assert src.qc.segments == 1


def test_blocks_never_exceed_batch_seconds_however_long_the_idle_sleep(tmp_path):
    """An idle-sleep period is filled in blocks of at most ``batch_seconds`` (a period of 97 days
    after one corrupt record time once asked for 2.8 GiB in one block); the same samples as one
    read in large blocks."""
    counts = _signal(3000, [(0, 100), (2900, 2950)])
    _write(tmp_path / "w.gt3x", counts)
    with Gt3xReader(tmp_path / "w.gt3x", batch_seconds=60) as src:
        blocks = list(src)
    assert max(b.n for b in blocks) <= 60 * RATE and len(blocks) >= 3000 // 60
    _, whole = _read(tmp_path / "w.gt3x")
    small = Block.concat(blocks)
    assert np.array_equal(small.time_ns, whole.time_ns) and np.array_equal(small.accel, whole.accel)
    assert np.array_equal(small.per_sample[PER_SAMPLE_IDLE_SLEEP], whole.per_sample[PER_SAMPLE_IDLE_SLEEP])
    assert small.per_sample[PER_SAMPLE_IDLE_SLEEP].sum() > 2700 * RATE


def test_idle_sleep_never_enters_the_calibration_windows(tmp_path):
    counts = _signal(400, [(0, 100), (200, 250)])
    _write(tmp_path / "w.gt3x", counts)
    op = WindowFeaturesOperator(RATE, min_fill=0.0)
    with open_recording(tmp_path / "w.gt3x") as src:
        blocks = list(src)
    f = op.push(Block.concat(blocks))
    f = type(f).concat([f, op.flush()])
    idle = Block.concat(blocks).per_sample[PER_SAMPLE_IDLE_SLEEP]
    assert f.n.sum() == (idle == 0).sum()
    # every 10 s window of the idle stretches is gone; the ones before sleep are kept
    w = (f.start_ns // 10**9 - T0).tolist()
    assert 100 in w and 110 not in w and 190 not in w and 200 in w and 260 not in w
    # the default fill rule drops what idle sleep leaves of a window
    op = WindowFeaturesOperator(RATE)
    with open_recording(tmp_path / "w.gt3x") as src:
        n = sum(len(op.push(b)) for b in src) + len(op.flush())
    assert n == 10 + 1 + 5 + 1  # moving 0-100 s, still 100-110 s, moving 200-250 s, still 250-260 s


@pytest.fixture(scope="module")
def simulated(tmp_path_factory):
    """A simulated 6 h wrist recording at 30 Hz with idle sleep, processed once."""
    from stillpoint.tools.cli import main
    d = tmp_path_factory.mktemp("gt3xsim")
    rec = d / "sim.gt3x"
    assert main(["simulate", "--device", "gt3x", "--hz", "30", "--days", "0.25", "-o", str(rec),
                 "-q", "--start", "2025-03-03T20:00:00Z"]) == 0
    assert main(["process", str(rec), "-o", str(d / "sim.mcap"), "-q"]) == 0
    return d, rec


def test_simulated_gt3x_processes_with_idle_sleep_column(simulated):
    d, rec = simulated
    with Gt3xReader(rec) as src:
        flags = np.concatenate([b.per_sample[PER_SAMPLE_IDLE_SLEEP] for b in src])
    assert src.idle_sleep_s > 600  # the simulated wearer is still for long stretches
    with gzip.open(d / "sim.epochs.csv.gz", "rt") as f:
        head = f.readline().strip().split(",")
        rows = [line.rstrip("\n").split(",") for line in f]
    i = head.index("idle_sleep")
    assert head[i - 1] == "filter_warmup"
    n = np.array([int(r[head.index("n")]) for r in rows])
    share = np.array([float(r[i]) if r[i] else 0.0 for r in rows])
    # the column's idle samples add up to the reader's flags
    assert abs(float((share * n).sum()) - float(flags.sum())) < 0.5 * len(rows)
    assert share.max() == 1.0 and share.min() == 0.0


def test_tables_from_the_log_keep_idle_sleep(simulated, tmp_path):
    from stillpoint.engine.workflows.tables_from_mcap import tables_from_mcap
    d, _ = simulated
    ep, dp = tmp_path / "e.csv.gz", tmp_path / "d.csv"
    tables_from_mcap(d / "sim.mcap", ep, dp)
    with gzip.open(ep, "rt") as f:
        again = f.read().splitlines()
    with gzip.open(d / "sim.epochs.csv.gz", "rt") as f:
        first = f.read().splitlines()
    k = first[0].split(",").index("idle_sleep") + 1
    assert [r.split(",")[:k] for r in again] == [r.split(",")[:k] for r in first]


def test_stillpoint_read_has_idle_sleep(simulated):
    import stillpoint
    _, rec = simulated
    df = stillpoint.read(rec)
    with Gt3xReader(rec) as src:
        flags = np.concatenate([b.per_sample[PER_SAMPLE_IDLE_SLEEP] for b in src])
    assert df["idle_sleep"].dtype == bool and np.array_equal(df["idle_sleep"].to_numpy(), flags > 0)


def test_simulated_file_is_a_zip_of_log_and_info(simulated):
    _, rec = simulated
    with zipfile.ZipFile(rec) as z:
        assert z.namelist() == ["log.bin", "info.txt"]
        info = z.read("info.txt").decode()
    assert "Acceleration Scale: 256.0\r\n" in info and "Sample Rate: 30\r\n" in info


# ---------------------------------------------------------------------- damage found by fuzzing
def _members(path) -> dict:
    with zipfile.ZipFile(path) as z:
        return {n: z.read(n) for n in z.namelist()}


def _zip(path, members: dict, compress=zipfile.ZIP_STORED):
    with zipfile.ZipFile(path, "w", compress) as z:
        for n, b in members.items():
            z.writestr(n, b)
    return path


def test_bad_crc_keeps_every_sample_and_says_so(tmp_path):
    """zipfile drops the data of the read that meets a bad CRC-32; the reader keeps it all and
    logs the damage (the same samples whatever the block size)."""
    counts = _signal(60, [(0, 60)])
    _write(tmp_path / "w.gt3x", counts)
    raw = bytearray((tmp_path / "w.gt3x").read_bytes())
    with zipfile.ZipFile(tmp_path / "w.gt3x") as z:
        zi = z.getinfo("log.bin")
    crc = zi.CRC.to_bytes(4, "little")
    i = raw.index(crc)  # the local header's CRC field
    raw[i] ^= 0xFF
    j = raw.index(crc, i + 4)  # the central directory's
    raw[j] ^= 0xFF
    p = tmp_path / "badcrc.gt3x"
    p.write_bytes(bytes(raw))
    for batch in (3600, 7):
        with Gt3xReader(p, batch_seconds=batch) as src:
            n = sum(b.n for b in src)
        assert n == counts.shape[0]
        assert [e.reason for e in src.qc.events] == ["damaged_member"]
        assert "CRC-32" in src.qc.events[0].detail


def test_actilife_export_of_a_tiny_scale_and_a_far_download_time(tmp_path):
    import io

    from stillpoint.drivers.actilife_csv import MAX_ZERO_RUN_S, write_actilife_csv
    counts = _signal(20, [(0, 20)])
    _write(tmp_path / "w.gt3x", counts)
    m = _members(tmp_path / "w.gt3x")
    info = m["info.txt"].decode()
    lines = [ln for ln in info.split("\r\n") if not ln.startswith(("Acceleration Scale", "Download Date"))]
    far = 662_065_056_000_000_000  # 2099-01-01 in .NET ticks
    m["info.txt"] = ("\r\n".join(lines) + f"Acceleration Scale: 1.0\r\nDownload Date: {far}\r\n").encode()
    p = _zip(tmp_path / "odd.gt3x", m)
    f = io.StringIO()
    with Gt3xReader(p) as src:
        rows = write_actilife_csv(src, f)
    assert rows["samples"] == counts.shape[0]
    assert rows["zero_rows"] == MAX_ZERO_RUN_S * RATE and rows["zero_seconds_cut"] > 0
    first = f.getvalue().split("\r\n")[11].split(",")
    assert first == [str(int(v)) for v in counts[0]]  # 1 LSB/g: the counts themselves


def test_legacy_activity_shorter_than_one_sample(tmp_path):
    """A legacy activity.bin of 3 bytes holds no whole sample (36 bits): none is returned."""
    p = _zip(tmp_path / "short.gt3x", {
        "activity.bin": b"\x00\x60\x08", "info.txt": b"Serial Number: NEO1C00000001\r\n"
        b"Sample Rate: 30\r\nStart Date: 638000000000000000\r\n"})
    with Gt3xReader(p) as src:
        assert sum(b.n for b in src) == 0


def test_replay_of_a_gt3x_log_gives_the_same_tables(simulated, tmp_path):
    """The log keeps the idle-sleep periods: a replay marks the same samples, so its epoch table
    (idle_sleep column included) and its sleep are the run's."""
    from stillpoint.tools.cli import main
    d, _ = simulated
    out = tmp_path / "re.mcap"
    assert main(["replay", str(d / "sim.mcap"), "-o", str(out), "-q"]) == 0
    with gzip.open(d / "sim.epochs.csv.gz", "rt") as f1, gzip.open(tmp_path / "re.epochs.csv.gz", "rt") as f2:
        a, b = f1.read(), f2.read()
    assert "idle_sleep" in a.splitlines()[0] and a == b


def test_cohort_finds_gt3x_files(tmp_path):
    from stillpoint.engine.cohort.plan import discover_inputs
    (tmp_path / "a").mkdir()
    for name in ("a/p1.gt3x", "a/p2.GT3X", "a/notes.txt"):
        (tmp_path / name).write_bytes(b"x")
    assert [p.name for p in discover_inputs([tmp_path])] == ["p1.gt3x", "p2.GT3X"]
