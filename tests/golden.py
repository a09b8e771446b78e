"""Golden hashes of `process`: the cases, how their outputs are fingerprinted, and the committed
fingerprints (tests/data/golden_hashes.json).

A case is one `stillpoint process` run on a short simulated recording (fixed seed) or on a real
file of STILLPOINT_REAL_DATA. Its fingerprint is a flat mapping name -> SHA-256:

- ``input``: the recording processed (a simulated one is built first; its hash tells a change of
  the simulator from a change of the processing);
- ``mcap:topic:<topic>``: every message of the topic in file order (log time, publish time, data),
  with the topic's schema and channel metadata;
- ``mcap:metadata:<name>``: each metadata record (name, then its keys and values sorted);
- ``mcap:attachment:<name>``: each attachment's media type and data;
- ``file:<name>``: every other file the run wrote (epoch, day and nights tables, ...), a
  ``.gz`` file by its decompressed text (the compressor's bytes are not the product's output).

Chunk compression and the MCAP index are left out on purpose: they depend on the zstd library, not
on the product. The fitted numbers are pinned to the test environment's numpy and scipy (the
``test`` extra); a new numpy/scipy release that moves a last bit is a legitimate regeneration too. ``tools/golden_hashes.py`` recomputes every case and rewrites the JSON file.
"""

from __future__ import annotations

import gzip
import hashlib
import json
import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Optional

HASHES_PATH = Path(__file__).resolve().parent / "data" / "golden_hashes.json"
REAL_DATA_ENV = "STILLPOINT_REAL_DATA"

REGENERATE_HELP = (
    "Regenerating is legitimate only when the change of output is deliberate: a new or changed "
    "column, topic, metadata field or number that the commit names and explains (e.g. 'day table: "
    "new calibration_source column; golden hashes regenerated'). A refactoring, a speed-up or a "
    "clean-up must leave every hash unchanged; if one moved, the change altered the product's "
    "output and that is the bug to find. Regenerate with `python tools/golden_hashes.py` "
    "(STILLPOINT_REAL_DATA set), check `git diff tests/data/golden_hashes.json` lists only the "
    "outputs you meant to change, and commit the JSON file with the change that caused it.")


@dataclass(frozen=True)
class Case:
    """One `process` run: its input (simulated or a real file) and command-line options."""

    name: str
    args: tuple[str, ...]
    real: Optional[str] = None  # file name under STILLPOINT_REAL_DATA
    simulate: dict = field(default_factory=dict)  # simulate_recording keywords (name + ".cwa")
    suffix: str = ".cwa"

    @property
    def needs_real_data(self) -> bool:
        return self.real is not None


# A simulated day from 14:00 UTC crossing the spring DST change of Europe/London (2025-03-30
# 01:00 UTC) at 12.5 Hz: calibration is fitted and applied (batch, and accepted online), a night is
# slept, and the day table, the nights table and UTC offsets on both sides of the change are written. The real files cover the
# readers (AX3 packed, AX3 with corrupt blocks, AX6 with a gyro, GENEActiv with its header zone)
# and runs whose calibration is not applied.
_SIM = dict(device="ax3", days=1.0, hz=12.5, seed=20251129, start="2025-03-29T14:00:00Z")
CASES: tuple[Case, ...] = (
    Case("sim_ax3_batch_london", ("--timezone", "Europe/London"), simulate=_SIM),
    Case("sim_ax3_online_london", ("--timezone", "Europe/London", "--mode", "online"),
         simulate=_SIM),
    Case("real_ax3_ggirread", ("--timezone", "Europe/Amsterdam"),
         real="ax3_ggirread_testfile_100hz_145blocks.cwa"),
    Case("real_ax3_ggirread_corrupt", (),
         real="ax3_ggirread_corrupt_blocks_0_13_14_142_143_144.cwa"),
    Case("real_ax6_ggirread", ("--timezone", "+01:00"),
         real="ax6_ggirread_testfile_100hz_16g_gyro250dps.cwa"),
    Case("real_geneactiv_sleeppy", (), real="geneactiv_sleeppy_test_100hz_64pages.bin",
         suffix=".bin"),
    Case("real_geneactiv_genearead_online", ("--mode", "online"),
         real="geneactiv_genearead_TESTfile_100hz_104pages.bin", suffix=".bin"),
)


def _sha(*parts: bytes) -> hashlib._Hash:
    h = hashlib.sha256()
    for p in parts:
        h.update(len(p).to_bytes(8, "little"))
        h.update(p)
    return h


def fingerprint_mcap(path: Path) -> dict[str, str]:
    """name -> SHA-256 of each topic's messages, each metadata record and each attachment."""
    from mcap.reader import make_reader

    out: dict[str, hashlib._Hash] = {}
    with open(path, "rb") as f:
        reader = make_reader(f)
        for schema, channel, msg in reader.iter_messages(log_time_order=False):
            key = f"mcap:topic:{channel.topic}"
            h = out.get(key)
            if h is None:
                head = json.dumps({"schema": None if schema is None else
                                   [schema.name, schema.encoding, schema.data.hex()],
                                   "encoding": channel.message_encoding,
                                   "metadata": sorted(channel.metadata.items())}).encode()
                h = out[key] = _sha(head)
            h.update(msg.log_time.to_bytes(8, "little"))
            h.update(msg.publish_time.to_bytes(8, "little"))
            h.update(len(msg.data).to_bytes(8, "little"))
            h.update(msg.data)
    with open(path, "rb") as f:
        reader = make_reader(f)
        seen: dict[str, int] = {}
        for md in reader.iter_metadata():
            n = seen[md.name] = seen.get(md.name, 0) + 1
            key = f"mcap:metadata:{md.name}" + (f"#{n}" if n > 1 else "")
            out[key] = _sha(json.dumps(sorted(md.metadata.items())).encode())
    with open(path, "rb") as f:
        reader = make_reader(f)
        for att in reader.iter_attachments():
            out[f"mcap:attachment:{att.name}"] = _sha(att.media_type.encode(), bytes(att.data))
    return {k: v.hexdigest() for k, v in sorted(out.items())}


def fingerprint_file(path: Path) -> str:
    """SHA-256 of a file's content (a ``.gz`` file's decompressed content)."""
    opener: Callable = gzip.open if path.suffix == ".gz" else open
    h = hashlib.sha256()
    with opener(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def real_data_dir() -> Optional[Path]:
    value = os.environ.get(REAL_DATA_ENV)
    return Path(value) if value else None


_SIMULATED: dict[str, Path] = {}  # simulate_recording keywords -> a file built in this process


def _input(case: Case, dest: Path) -> None:
    if case.real is not None:
        folder = real_data_dir()
        if folder is None:
            raise RuntimeError(f"{REAL_DATA_ENV} is not set: case {case.name} needs {case.real}")
        shutil.copyfile(folder / case.real, dest)
        return
    key = json.dumps(case.simulate, sort_keys=True)
    built = _SIMULATED.get(key)
    if built is None or not built.is_file():
        from stillpoint.engine.sim.record import simulate_recording

        simulate_recording(dest, truth_path=False, labels_path=False, **case.simulate)
        _SIMULATED[key] = dest
    else:
        shutil.copyfile(built, dest)


def run_case(case: Case, workdir: Path) -> dict[str, str]:
    """Build or copy the case's input into an empty ``workdir``, run `process` there on relative
    paths (the logs name their input as given), and fingerprint what it wrote."""
    from stillpoint.tools.cli import main

    workdir.mkdir(parents=True, exist_ok=True)
    src, out = workdir / f"rec{case.suffix}", workdir / "rec.mcap"
    _input(case, src)
    before = os.getcwd()
    os.chdir(workdir)
    try:
        code = main(["process", src.name, "-o", out.name, "-q", *case.args])
    finally:
        os.chdir(before)
    if code != 0:
        raise RuntimeError(f"case {case.name}: process exited {code}")
    prints = {"input": fingerprint_file(src)}
    prints.update(fingerprint_mcap(out))
    for p in sorted(workdir.iterdir()):
        if p.is_file() and p not in (src, out):
            prints[f"file:{p.name}"] = fingerprint_file(p)
    return prints


def load_hashes() -> dict[str, dict[str, str]]:
    return json.loads(HASHES_PATH.read_text())


def save_hashes(hashes: dict[str, dict[str, str]]) -> None:
    HASHES_PATH.write_text(json.dumps(hashes, indent=1, sort_keys=True) + "\n")


def differences(expected: dict[str, str], got: dict[str, str]) -> list[str]:
    """One line per output whose fingerprint differs, appeared or disappeared."""
    lines = []
    for key in sorted(set(expected) | set(got)):
        if key not in got:
            lines.append(f"  {key}: no longer written")
        elif key not in expected:
            lines.append(f"  {key}: new output")
        elif expected[key] != got[key]:
            lines.append(f"  {key}: {expected[key][:12]} -> {got[key][:12]}")
    return lines
