"""The plan of a cohort run: which recordings, their keys, their output folders, and shards.

A file's **key** is the SHA-256 of (its first ``HEADER_BYTES`` bytes, its size in bytes, the
canonical settings, the code version). Its path and modification time are not in the key: a
cohort copied or mounted elsewhere maps to the same folders, and the same inputs with the same
settings always map to the same output folder, so a rerun finds what is done. The code version
is the package version plus a digest of the engine and driver sources, so outputs made by
different code never pass for each other.

Output folder of a file: ``OUTDIR/files/<key[:2]>/<name>-<key[:16]>`` (256 buckets, so no folder
holds more than a few hundred entries at 100,000 files).

A file that cannot even be opened to take its key (missing, permission denied) is still in the
plan, with ``error`` set and a key made from its path, so it lands in the failure table.

A manifest CSV may also give, per file, ``timezone`` (the participant's zone for that file: it
replaces the run's ``--timezone`` for it and is part of its key) and ``participant`` (the id
the day tables and the per-participant summary are grouped by; default: the recording's
subject code, else its file name).
"""

from __future__ import annotations

import csv
import errno
import hashlib
import io
import json
import os
import re
from dataclasses import dataclass, field, replace
from functools import lru_cache
from pathlib import Path
from typing import Iterable, Optional

from stillpoint.engine.core.paths import not_a_file
from stillpoint.engine.core.errors import StillpointError
from stillpoint.engine.core.outputs import OutputError, atomic_output

HEADER_BYTES = 8192  # .cwa header (1 KiB) + first data sectors; GENEActiv's text header (~3 KiB)
KEY_FORMAT = 1  # bump when what goes into a key changes
RECORDING_SUFFIXES = (".cwa", ".cwa.gz", ".bin", ".bin.gz", ".gt3x")
MANIFEST = "manifest.csv"
PLAN_FILE = "cohort.json"
FILES_DIR = "files"
MANIFEST_FIELDS = ("path", "size", "key", "folder", "error", "timezone", "participant")
# manifest CSV columns read per file besides ``path`` (first name found wins)
ZONE_COLUMNS = ("timezone", "time_zone", "tz")
PARTICIPANT_COLUMNS = ("participant", "participant_id", "id")


class CohortInputError(StillpointError):
    """An input given to a cohort run does not exist or is not a recording, folder or manifest."""


# ---------------------------------------------------------------------------- versions
@lru_cache(maxsize=1)
def code_version() -> str:
    """``<package version>+<12 hex digits of the engine and driver sources>``."""
    try:
        from importlib.metadata import version
        v = version("stillpoint")
    except Exception:  # not installed (running from a source tree)
        v = "0+unknown"
    import stillpoint.drivers as drivers
    import stillpoint.engine as engine
    h = hashlib.sha256()
    for pkg in (engine, drivers):
        root = Path(pkg.__file__).resolve().parent
        for f in sorted(root.rglob("*.py")):
            h.update(f.relative_to(root).as_posix().encode())
            h.update(f.read_bytes())
    return f"{v}+{h.hexdigest()[:12]}"


def default_table_options() -> dict:
    """The epoch/day table options a cohort's settings carry when none are given (those of
    ``process``, sleep included): a plan's settings always hold them, so they are part of every
    key."""
    from stillpoint.engine.operators.nonwear import DEFAULT_VERSION
    from stillpoint.engine.tables.days import ENMO_BANDS_MG, MVPA_BOUT_S, VALID_DAY_HOURS
    return {"nonwear_version": DEFAULT_VERSION, "valid_day_hours": float(VALID_DAY_HOURS),
            "enmo_bands_mg": [float(x) for x in ENMO_BANDS_MG], "mvpa_bout_s": float(MVPA_BOUT_S),
            "sleep": True}


def canonical_settings(settings) -> str:
    """The settings as canonical JSON (sorted keys, no spaces): what goes into every key."""
    d = settings.to_dict() if hasattr(settings, "to_dict") else dict(settings)
    return json.dumps(d, sort_keys=True, separators=(",", ":"), allow_nan=False)


# ---------------------------------------------------------------------------- inputs
def is_recording_name(name: str) -> bool:
    n = name.lower()
    return n.endswith(RECORDING_SUFFIXES)


def _expand(text: str) -> Path:
    """``~`` and ``~user`` expanded; a user the system does not know is left as written (the
    file then fails as missing, with its name)."""
    try:
        return Path(text).expanduser()
    except RuntimeError:
        return Path(text)


def _read_manifest_csv(path: Path, attributes: Optional[dict] = None) -> list[Path]:
    """A manifest CSV: a header row with a ``path`` column, or one path per line (first column;
    then the first row names a recording); a header row without ``path`` is refused;
    relative paths are relative to the CSV's folder; blank lines and lines starting with # are
    ignored. With a header, the optional ``timezone`` and ``participant`` columns of each row
    go into ``attributes`` (absolute path -> {"timezone", "participant"})."""
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeError) as e:
        raise CohortInputError(f"{path}: cannot read the manifest ({e})") from None
    try:
        rows = [r for r in csv.reader(io.StringIO(text)) if r and r[0].strip() and not r[0].startswith("#")]
    except csv.Error as e:  # e.g. a cell over csv's field limit (131,072 characters)
        raise CohortInputError(f"{path}: not a readable manifest ({e})") from None
    if not rows:
        raise CohortInputError(f"{path}: the manifest lists no files")
    header = [c.strip().lower() for c in rows[0]]
    first = _expand(rows[0][0].strip())
    try:
        names_a_file = (any(is_recording_name(c.strip()) for c in rows[0])
                        or (first if first.is_absolute() else path.parent / first).is_file())
    except (OSError, ValueError):  # a name too long for the system, a NUL byte
        names_a_file = False
    if "path" not in header and not names_a_file:  # a header row without the paths' column
        found = ", ".join(c.strip() for c in rows[0])[:200]
        raise CohortInputError(f"{path}: no 'path' column (columns found: {found}); name the "
                               "column of the recordings' paths 'path', or list one path per line")
    col = header.index("path") if "path" in header else 0
    extra = {}
    if "path" in header:
        rows = rows[1:]
        for name, cands in (("timezone", ZONE_COLUMNS), ("participant", PARTICIPANT_COLUMNS)):
            found = [header.index(c) for c in cands if c in header]
            if found:
                extra[name] = found[0]
    out = []
    for r in rows:
        p = _expand(r[col].strip())
        p = p if p.is_absolute() else path.parent / p
        out.append(p)
        if attributes is not None and extra:
            vals = {k: (r[i].strip() if i < len(r) else "") for k, i in extra.items()}
            if "timezone" in vals and vals["timezone"]:
                from stillpoint.engine.timezones import ZoneError, parse_zone
                try:
                    parse_zone(vals["timezone"])
                except ZoneError as e:
                    raise CohortInputError(f"{path}: row of {p.name}: {e}") from None
            attributes[str(p.absolute())] = {k: v for k, v in vals.items() if v}
    return out


def discover_inputs(inputs: Iterable, attributes: Optional[dict] = None) -> list[Path]:
    """Files, folders (searched recursively for .cwa/.cwa.gz/.bin/.bin.gz/.gt3x, any case) and manifest
    CSVs -> absolute paths, sorted, each once. A name on the command line that does not exist is
    an error; a file listed in a manifest that does not exist is kept (it fails as unreadable).
    ``attributes``: a dict that receives the manifests' per-file ``timezone`` / ``participant``
    (absolute path -> values; pass it on to ``make_plan``)."""
    found: dict[str, Path] = {}
    for raw in inputs:
        p = Path(raw).expanduser()
        if p.is_dir():
            for root, dirs, files in os.walk(p):
                dirs[:] = sorted(d for d in dirs if not d.startswith("."))
                for name in files:
                    if is_recording_name(name) and not name.startswith("."):
                        q = Path(root, name).absolute()
                        found[str(q)] = q
        elif p.name.lower().endswith(".csv") and p.is_file():
            for q in _read_manifest_csv(p, attributes):
                q = q.absolute()
                found[str(q)] = q
        elif p.exists() or p.is_symlink():
            q = p.absolute()
            found[str(q)] = q
        else:
            raise CohortInputError(f"{p}: no such file or folder")
    return [found[k] for k in sorted(found)]


def fingerprint(path: Path) -> dict:
    """Size, SHA-256 of the first ``HEADER_BYTES`` bytes, and modification time (not in the key).
    A path that is not a regular file raises before it is opened (a named pipe would wait)."""
    kind = not_a_file(os.stat(path).st_mode)
    if kind:
        raise OSError(errno.EINVAL, f"is {kind}, not a recording file", str(path))
    with open(path, "rb") as f:
        st = os.fstat(f.fileno())
        head = f.read(HEADER_BYTES)
    return {"size": st.st_size, "header_sha256": hashlib.sha256(head).hexdigest(),
            "mtime_ns": st.st_mtime_ns}


def make_key(fp: dict, settings_json: str, code: str) -> str:
    blob = json.dumps({"key_format": KEY_FORMAT, "header_sha256": fp["header_sha256"],
                       "size": fp["size"], "settings": settings_json, "code": code},
                      sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(blob.encode()).hexdigest()


def _safe_name(path: Path) -> str:
    name = path.name
    for suf in sorted(RECORDING_SUFFIXES, key=len, reverse=True):
        if name.lower().endswith(suf):
            name = name[: -len(suf)]
            break
    name = re.sub(r"[^A-Za-z0-9._-]+", "_", name).strip("._") or "recording"
    return name[:60]


def folder_for(path: Path, key: str) -> str:
    """The output folder of a file, relative to OUTDIR (posix form)."""
    return f"{FILES_DIR}/{key[:2]}/{_safe_name(path)}-{key[:16]}"


def describe_input_error(e: OSError) -> str:
    from stillpoint.engine.core.outputs import describe_os_error
    if isinstance(e, FileNotFoundError):
        return "no such file (deleted, moved, or a broken link)"
    return describe_os_error(e)


# ---------------------------------------------------------------------------- the plan
@dataclass(frozen=True)
class Entry:
    """One input file of the plan."""

    path: str
    size: int
    key: str
    folder: str  # relative to OUTDIR
    error: str = ""  # set when the file could not be opened to take its key
    timezone: str = ""  # the manifest's zone for this file ("": the run's setting)
    participant: str = ""  # the manifest's participant id ("": from the recording)

    def shard(self, n: int) -> int:
        return int(self.key[:8], 16) % n

    def as_row(self) -> dict:
        return {"path": self.path, "size": self.size, "key": self.key, "folder": self.folder,
                "error": self.error, "timezone": self.timezone, "participant": self.participant}


def entry_settings(settings: dict, entry) -> dict:
    """The settings one file is processed with: the run's, with the manifest's zone for that
    file in place of the run's ``timezone`` (``entry``: an Entry or its row)."""
    tz = entry.get("timezone") if isinstance(entry, dict) else getattr(entry, "timezone", "")
    if not tz:
        return settings
    return dict(settings, timezone=tz)


@dataclass
class Plan:
    """Every input's entry, with the settings and code version the keys were made from."""

    settings: dict
    code_version: str
    entries: list[Entry] = field(default_factory=list)
    duplicates: list[tuple[str, str]] = field(default_factory=list)  # (path, same as path)

    @property
    def settings_json(self) -> str:
        return canonical_settings(self.settings)

    def shard(self, k: int, n: int) -> "Plan":
        """The entries of shard ``k`` of ``n`` (by key, so every shard agrees without talking)."""
        if not (n >= 1 and 0 <= k < n):
            raise CohortInputError(f"--shard {k}/{n}: need 0 <= K < N")
        return replace(self, entries=[e for e in self.entries if e.shard(n) == k])

    def write(self, outdir) -> None:
        """``manifest.csv`` and ``cohort.json`` in OUTDIR (created if needed), rewritten only when
        they change (so shards of a job array, which all plan the same cohort, do not fight over
        them)."""
        outdir = Path(outdir)
        outdir.mkdir(parents=True, exist_ok=True)
        buf = io.StringIO()
        w = csv.DictWriter(buf, fieldnames=MANIFEST_FIELDS, lineterminator="\n")
        w.writeheader()
        for e in self.entries:
            w.writerow(e.as_row())
        meta = json.dumps({"settings": self.settings, "code_version": self.code_version,
                           "key_format": KEY_FORMAT, "files": len(self.entries)},
                          indent=2, sort_keys=True) + "\n"
        for name, text in ((MANIFEST, buf.getvalue()), (PLAN_FILE, meta)):
            target = outdir / name
            try:
                if target.read_text(encoding="utf-8") == text:
                    continue
            except (OSError, UnicodeError):
                pass
            try:
                with atomic_output(target, binary=False, what="cohort plan") as f:
                    f.write(text)
            except OutputError as e:
                if "another stillpoint run" not in str(e):  # a concurrent shard writes the same
                    raise


def make_plan(paths: Iterable[Path], settings, *, code: Optional[str] = None,
              attributes: Optional[dict] = None) -> Plan:
    """Fingerprint every file and make its key and folder (reads ``HEADER_BYTES`` per file).
    ``attributes`` (from ``discover_inputs``): per-file ``timezone`` and ``participant``; a
    file's zone is part of its key."""
    settings_dict = settings.to_dict() if hasattr(settings, "to_dict") else dict(settings)
    settings_dict.setdefault("tables", default_table_options())
    sj = canonical_settings(settings_dict)
    code = code or code_version()
    plan = Plan(settings=settings_dict, code_version=code)
    seen: dict[str, str] = {}
    for p in paths:
        p = Path(p)
        attrs = (attributes or {}).get(str(p.absolute()), {})
        tz, who = attrs.get("timezone", ""), attrs.get("participant", "")
        sj_file = canonical_settings(entry_settings(settings_dict, {"timezone": tz})) if tz else sj
        try:
            fp = fingerprint(p)
            key, size, err = make_key(fp, sj_file, code), fp["size"], ""
        except OSError as e:
            key = hashlib.sha256(f"unreadable\0{p}\0{sj}\0{code}".encode()).hexdigest()
            size, err = 0, f"cannot open: {describe_input_error(e)}"
        folder = folder_for(p, key)
        if folder in seen:  # the same bytes under the same name twice: processed once
            plan.duplicates.append((str(p), seen[folder]))
            continue
        seen[folder] = str(p)
        plan.entries.append(Entry(path=str(p), size=size, key=key, folder=folder, error=err,
                                  timezone=tz, participant=who))
    return plan


def read_plan(outdir: Path) -> Plan:
    """The plan last written to OUTDIR by ``cohort run``."""
    outdir = Path(outdir)
    try:
        meta = json.loads((outdir / PLAN_FILE).read_text(encoding="utf-8"))
        text = (outdir / MANIFEST).read_text(encoding="utf-8")
    except FileNotFoundError:
        raise CohortInputError(f"{outdir}: not a cohort folder (no {PLAN_FILE} / {MANIFEST}; "
                               "start one with `stillpoint cohort run`)") from None
    except (OSError, ValueError) as e:
        raise CohortInputError(f"{outdir}: cannot read the cohort plan ({e})") from None
    plan = Plan(settings=meta["settings"], code_version=meta["code_version"])
    for r in csv.DictReader(io.StringIO(text)):
        plan.entries.append(Entry(path=r["path"], size=int(r["size"] or 0), key=r["key"],
                                  folder=r["folder"], error=r.get("error") or "",
                                  timezone=r.get("timezone") or "",
                                  participant=r.get("participant") or ""))
    return plan
