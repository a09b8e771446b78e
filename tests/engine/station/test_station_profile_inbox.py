"""Study profiles (TOML) and the inbox (GENEActiv .bin / .cwa files dropped in a folder)."""

from __future__ import annotations

import datetime as dt
import time

import pytest

from stillpoint.engine.station.inbox import Inbox
from stillpoint.engine.station.ledger import Ledger
from stillpoint.engine.station.profile import ProfileError, StudyProfile, load_profile


def test_profile_values_and_times(tmp_path):
    p = tmp_path / "s.toml"
    p.write_text('[device]\nrate_hz = 25\nrange_g = 2\ngyro_dps = 500\nstart = "+90m"\nstop = "+7d"\n'
                 'session = "4242"\n[metadata]\nstudy = "A B"\n[station]\nclear_after_verify = true\n')
    prof = load_profile(p)
    assert prof.rate_code == 0xC0 | 8 and prof.clear_after_verify and not prof.configure_after
    assert prof.session_for(7) == 4242
    now = dt.datetime(2026, 1, 1, 12, 0, 0)
    start, stop, start_dt = prof.times(now)
    assert start == "2026/01/01,13:30:00" and stop == "2026/01/08,13:30:00"
    slots = prof.annotation_slots()
    assert len(slots) == 14 and "".join(slots) == "study=A+B"
    assert StudyProfile().session_for(2 ** 31 - 1) == 0  # increment wraps within 31 bits


@pytest.mark.parametrize("text, msg", [
    ('[device]\nrate_hz = 33\n', "AX rate must be"),
    ('[device]\nrange_g = 3\n', "range must be"),
    ('[device]\ngyro_dps = 300\n', "gyro_dps"),
    ('[device]\nstart = "tomorrow"\n', "neither"),
    ('[device]\nsession = "random"\n', "session must be"),
    ('[metadata]\nx = "' + "y" * 500 + '"\n', "device holds 448"),
    ('[device\n', "not valid TOML"),
    (b"MD\xfc\x01\x00\x00", "not a TOML text file"),  # e.g. a recording given by mistake
])
def test_profile_errors_name_the_file(tmp_path, text, msg):
    p = tmp_path / "bad.toml"
    p.write_bytes(text) if isinstance(text, bytes) else p.write_text(text)
    with pytest.raises(ProfileError, match=msg) as e:
        load_profile(p)
    assert str(p) in str(e.value)


def _settle(ib, timeout_s: float = 30.0) -> None:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end and not ib.idle():
        time.sleep(0.1)


def _inbox_with_one_file(tmp_path):
    """An inbox holding a short simulated GENEActiv p01.bin, an output folder with its ledger,
    and the Inbox once it has settled."""
    from stillpoint.engine.sim.record import simulate_recording
    inbox, out = tmp_path / "inbox", tmp_path / "out"
    inbox.mkdir()
    out.mkdir()
    simulate_recording(inbox / "p01.bin", device="geneactiv", days=0.01, truth_path=False)
    lg = Ledger(out)
    ib = Inbox(inbox, out, stable_s=0.2, ledger=lg)
    _settle(ib)
    return inbox, out, lg, ib


def test_inbox_ingests_stable_files_once(tmp_path):
    inbox, out, lg, ib = _inbox_with_one_file(tmp_path)
    names = sorted(x.name for x in out.iterdir() if not x.name.startswith("stillpoint-ledger"))
    assert len([n for n in names if n.endswith(".bin")]) == 1 and len([n for n in names if n.endswith(".mcap")]) == 1
    recs = lg.downloads()
    assert len(recs) == 1 and recs[0].verified and recs[0].bytes == (inbox / "p01.bin").stat().st_size
    ib.step()
    assert len(lg.downloads()) == 1  # once


def test_inbox_ingests_the_same_bytes_once_and_is_not_the_output_folder(tmp_path):
    """A file dropped again under another name is not ingested again (its SHA-256 is in the
    ledger); an inbox that is the output folder is refused (its raw copies would come back in,
    for ever)."""
    import shutil

    from stillpoint.engine.core.outputs import OutputError
    inbox, out, lg, ib = _inbox_with_one_file(tmp_path)
    shutil.copy(inbox / "p01.bin", inbox / "p01-again.bin")
    _settle(ib)
    assert len(lg.downloads()) == 1
    assert "already ingested as" in ib.done[str(inbox / "p01-again.bin")]
    assert "same SHA-256" in ib.done[str(inbox / "p01-again.bin")]
    with pytest.raises(OutputError, match="cannot be the station's output folder"):
        Inbox(out, out, ledger=lg)


def test_inbox_flags_an_incomplete_file(tmp_path):
    from stillpoint.engine.sim.record import simulate_recording
    inbox, out = tmp_path / "inbox", tmp_path / "out"
    inbox.mkdir()
    out.mkdir()
    f = inbox / "p02.bin"
    simulate_recording(f, device="geneactiv", days=0.01, truth_path=False)
    data = f.read_bytes()
    f.write_bytes(data[: int(len(data) * 0.7)])  # extraction stopped part-way
    lg = Ledger(out)
    ib = Inbox(inbox, out, stable_s=0.2, ledger=lg)
    _settle(ib)
    assert ib.errors and "incomplete" in ib.errors[0]
    assert lg.downloads()[0].verified is False


_KILLED_INGEST = """
import sys
from pathlib import Path
from stillpoint.engine.station.inbox import Inbox
from stillpoint.engine.station.ledger import Ledger
inbox, out = Path(sys.argv[1]), Path(sys.argv[2])
Inbox(inbox, out, stable_s=0.0, ledger=Ledger(out)).ingest(inbox / "p01.bin")
"""


@pytest.mark.parametrize("step", ["download:completing", "completion:raw-renamed"])
def test_a_station_killed_while_the_inbox_completes_is_reconciled(tmp_path, step):
    """The inbox completes through the ledger like a download: a kill between the ledger's
    'completing' and its 'verified' leaves a row the next start completes (both outputs under
    their final names, the row verified); the file is then not ingested again."""
    import hashlib
    import os
    import subprocess
    import sys

    from stillpoint.engine.sim.record import simulate_recording
    from stillpoint.engine.station.completion import reconcile
    inbox, out = tmp_path / "inbox", tmp_path / "out"
    inbox.mkdir()
    out.mkdir()
    simulate_recording(inbox / "p01.bin", device="geneactiv", days=0.01, truth_path=False)
    r = subprocess.run([sys.executable, "-c", _KILLED_INGEST, str(inbox), str(out)], timeout=300,
                       env=dict(os.environ, STILLPOINT_KILL_AT=step), capture_output=True)
    assert r.returncode == -9, r.stderr.decode()[-500:]
    lg = Ledger(out)
    assert [x.state for x in lg.downloads()] == ["completing"]
    assert "completed after a restart" in reconcile(lg)[0]
    rec = lg.downloads()[0]
    assert rec.verified and rec.device_type == "GENEActiv"
    raw = (inbox / "p01.bin").read_bytes()
    assert open(rec.cwa_path, "rb").read() == raw and rec.sha256 == hashlib.sha256(raw).hexdigest()
    assert os.path.exists(rec.mcap_path)
    assert sorted(p.name for p in out.iterdir() if ".part" in p.name or "unverified" in p.name) == []
    assert "already ingested" in Inbox(inbox, out, stable_s=0.0, ledger=lg).ingest(inbox / "p01.bin")
