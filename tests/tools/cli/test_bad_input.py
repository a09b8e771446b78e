"""Bad input through the CLI: exit code 2, exactly one line on stderr naming the file, no traceback;
and the same inputs through the API raise typed errors (never an exception from inside numpy)."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

from stillpoint.drivers import open_recording
from stillpoint.engine.core.errors import (CorruptRecordingError, RecordingError, StillpointError,
                                       TruncatedRecordingError, UnsupportedFormatError)
from stillpoint.drivers.geneactiv import GeneactivReader, GeneactivWriter
from stillpoint.tools.cli import main

T0 = 1_650_000_000_000_000_000


def _bin(path, pages=4):
    w = GeneactivWriter(path, rate_hz=100.0)
    n = pages * 300
    w.write(T0 + np.arange(n) * 10_000_000, np.zeros((n, 3), int))
    w.close()
    return path


def _cwa(path, sectors=10):
    cwa = pytest.importorskip("stillpoint.drivers.cwa")
    w = cwa.CwaWriter(str(path), rate_hz=100.0)
    n = 120 * sectors
    w.write(T0 + np.arange(n) * 10_000_000, np.zeros((n, 3), int))
    w.close()
    return path, cwa


def make_zero_bin(d):
    p = d / "zero.bin"
    p.write_bytes(b"")
    return p


def make_zero_cwa(d):
    p = d / "zero.cwa"
    p.write_bytes(b"")
    return p


def make_random(d):
    p = d / "random.cwa"
    p.write_bytes(np.random.default_rng(7).integers(0, 256, 5000, dtype=np.uint8).tobytes())
    return p


def make_random_bin(d):
    p = d / "random.bin"
    p.write_bytes(np.random.default_rng(8).integers(0, 256, 5000, dtype=np.uint8).tobytes())
    return p


def make_text_cwa(d):
    p = d / "notes.cwa"
    p.write_text("these are my notes, not a recording\n" * 20)
    return p


def make_truncated_cwa(d):
    p, _ = _cwa(d / "cut.cwa")
    p.write_bytes(p.read_bytes()[:700])  # inside the 1024-byte header
    return p


def make_all_corrupt_cwa(d):
    p, cwa = _cwa(d / "allbad.cwa")
    for i in range(10):
        cwa.corrupt_sector(str(p), i, "checksum")
    return p


def make_header_cut_bin(d):
    p = _bin(d / "cut.bin")
    data = p.read_bytes()
    p.write_bytes(data[:data.find(b"Calibration Data")])
    return p


def make_all_corrupt_bin(d):
    p = _bin(d / "allbad.bin")
    data = p.read_bytes()
    head = data.find(b"Recorded Data")
    body = data[head:].replace(b"000000000000", b"00000000000G")  # every page holds a non-hex char
    p.write_bytes(data[:head] + body)
    return p


def make_genea(d):
    p = d / "genea.bin"
    p.write_bytes(b"GENEA/1.00\r\nDevice Serial:01275\r\n" + b"0" * 2000)
    return p


def make_missing(d):
    return d / "does_not_exist.cwa"


def make_char_device(d):
    return os.devnull  # reads as empty: refused as a device, not as an empty file


CASES = {
    "zero_length_bin": (make_zero_bin, TruncatedRecordingError, "empty"),
    "zero_length_cwa": (make_zero_cwa, TruncatedRecordingError, "empty"),
    "random_bytes": (make_random, UnsupportedFormatError, "not a recognised recording"),
    "random_bytes_bin": (make_random_bin, UnsupportedFormatError, "not a recognised recording"),
    "text_named_cwa": (make_text_cwa, UnsupportedFormatError, "not a recognised recording"),
    "truncated_cwa": (make_truncated_cwa, TruncatedRecordingError, "header"),
    "all_corrupt_cwa": (make_all_corrupt_cwa, CorruptRecordingError, "readable"),
    "header_cut_bin": (make_header_cut_bin, TruncatedRecordingError, "header ends early"),
    "all_corrupt_bin": (make_all_corrupt_bin, CorruptRecordingError, "none of the 4 page"),
    "genea": (make_genea, UnsupportedFormatError, "original GENEA"),
    "missing": (make_missing, RecordingError, "no such file"),
    "char_device": (make_char_device, RecordingError, "is a character device"),
}


def _consume(path):
    src = open_recording(path)
    try:
        for _ in src:
            pass
    finally:
        src.close()


@pytest.mark.parametrize("case", sorted(CASES))
def test_api_raises_typed_error(tmp_path, case):
    make, err, msg = CASES[case]
    p = make(tmp_path)
    with pytest.raises(err, match=msg) as e:
        _consume(p)
    assert isinstance(e.value, StillpointError)
    assert str(p) in str(e.value)


# A real process for a representative subset (each start pays for importing every subcommand);
# every case goes through main() in-process below, where any escaping exception fails the test.
SUBPROCESS_CASES = ["zero_length_bin", "text_named_cwa", "all_corrupt_cwa", "header_cut_bin"]


# --header-only reads no data sectors/pages, so the all-corrupt files are not errors there
INSPECT_CASES = [(c, "inspect") for c in sorted(CASES)] + [
    (c, "inspect --header-only") for c in sorted(CASES) if not c.startswith("all_corrupt")]


@pytest.mark.parametrize("case,command", INSPECT_CASES)
def test_cli_inspect_in_process(tmp_path, case, command, capsys):
    make, _, msg = CASES[case]
    p = make(tmp_path)
    code = main(command.split() + [str(p)])
    out, err = capsys.readouterr()
    assert code == 2 and out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("stillpoint inspect: error: ")
    assert str(p) in lines[0] and msg in lines[0]


@pytest.mark.parametrize("case", SUBPROCESS_CASES)
def test_cli_inspect_exit_2_one_line(tmp_path, case):
    make, _, msg = CASES[case]
    p = make(tmp_path)
    env = dict(os.environ, PYTHONWARNINGS="ignore")
    r = subprocess.run([sys.executable, "-m", "stillpoint.tools", "inspect", str(p)],
                       capture_output=True, text=True, timeout=60, env=env)
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    assert "Traceback" not in r.stderr
    assert lines[0].startswith("stillpoint inspect: error: ") and str(p) in lines[0] and msg in lines[0]
    assert r.stdout == ""


@pytest.mark.parametrize("case", sorted(CASES))
def test_cli_export_exit_2_one_line(tmp_path, case, capsys):
    make, _, msg = CASES[case]
    p = make(tmp_path)
    out = tmp_path / "out.csv"
    code = main(["export", str(p), "-o", str(out)])
    _, err = capsys.readouterr()
    assert code == 2 and len(err.strip().splitlines()) == 1 and msg in err
    assert not out.exists() and not (tmp_path / "out.csv.partial").exists()


@pytest.mark.parametrize("command", ["inspect", "process", "replay", "recover", "report"])
def test_named_pipe_refused_without_waiting_for_a_writer(tmp_path, command):
    """A pipe given as the input (a FIFO, or `<(zcat rec.cwa.gz)`) is refused at once: opening
    it would wait for a writer, and recordings are read with seeks."""
    p = tmp_path / "pipe.cwa"
    os.mkfifo(p)
    args = [command, str(p)] + (["-o", str(tmp_path / "out.mcap")]
                                if command in ("process", "replay", "recover") else [])
    r = subprocess.run([sys.executable, "-m", "stillpoint.tools", *args], capture_output=True,
                       text=True, timeout=60, env=dict(os.environ, PYTHONWARNINGS="ignore"))
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1, r.stderr
    assert lines[0].startswith(f"stillpoint {command}: error: {p}: is a pipe, not a recording")
    assert sorted(x.name for x in tmp_path.iterdir()) == ["pipe.cwa"]


def test_real_genea_file_via_cli(real_file):
    p = real_file("NOT_geneactiv_original_GENEA_device_ggirread.bin")
    r = subprocess.run([sys.executable, "-m", "stillpoint.tools", "inspect", "--json", str(p)],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and r.stdout == ""
    assert r.stderr.count("\n") == 1 and "original GENEA" in r.stderr and "not supported" in r.stderr


def test_what_was_read_before_a_bad_region_is_kept(tmp_path):
    p = _bin(tmp_path / "tail.bin", pages=5)
    data = p.read_bytes()
    cut = [i for i in range(len(data)) if data.startswith(b"Recorded Data", i)][3]
    p.write_bytes(data[:cut] + os.urandom(3000).replace(b"\n", b" "))
    r = GeneactivReader(p)
    n = sum(b.n for b in r)
    assert n == 900
    assert [e.reason for e in r.qc.events] == ["desync", "page_count_mismatch"]
