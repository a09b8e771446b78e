"""Output files that are never written in place.

Every output stillpoint writes (MCAP logs, exports, simulated recordings, summaries, store
records, downloads) goes to ``<name>.part`` in the destination folder and is renamed onto
``<name>`` only when complete: flushed, fsync'ed, renamed atomically, the folder fsync'ed. So
an existing complete output is never destroyed by an interrupted run, and a file without the
``.part`` suffix is always complete.

A second writer to the same output is refused: the ``.part`` file is held with an exclusive
``flock`` for as long as it is being written. A ``.part`` left by a killed run (nobody holds its
lock) is kept, renamed to ``<name>.part.<UTC time>``, so nothing already written is lost; its
new name is reported in ``AtomicOutput.set_aside``.

``check_output_path`` (``check_output_folder`` for a folder) validates a destination before any
work starts (folder exists, is a folder, is writable, the name can be encoded, the path is not a
device, pipe or socket), so a long run cannot fail at its end for a reason that was knowable at
its start. A device such as
``/dev/null`` is refused rather than written: the rename that completes an output would put a
plain file in its place. So is a file the running command reads (``protect_inputs``: the command
line registers its inputs), and two outputs of one command that are the same file
(``check_distinct_outputs``). Commands that write named outputs (``simulate``, ``process``,
``replay``, ``export``, ``report``, ``recover``) also refuse an output that already exists
unless given ``--overwrite`` (``keep_existing_outputs``).

Links are never followed for the folder's entries (the folder itself may be a link): a
destination that is a symbolic link is refused (the rename would replace the link, and the user
named the link, not its target), the ``.part`` file is created with
``O_CREAT | O_EXCL | O_NOFOLLOW`` so a planted ``.part`` link or hard link never receives a
byte, and the rename that completes an output checks that the ``.part`` name still holds the
file that was written.
"""

from __future__ import annotations

import errno
import os
import stat
import time
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Iterator, Optional

from .paths import not_a_file
from .errors import StillpointError

try:  # POSIX; on other systems the second-writer guard is skipped
    import fcntl
except ImportError:  # pragma: no cover
    fcntl = None  # type: ignore[assignment]

PART_SUFFIX = ".part"
_CLOEXEC = getattr(os, "O_CLOEXEC", 0)
_NOFOLLOW = getattr(os, "O_NOFOLLOW", 0)
_NEW_PART = os.O_RDWR | os.O_CREAT | os.O_EXCL | _NOFOLLOW | _CLOEXEC  # never an existing file


class OutputError(StillpointError, OSError):
    """An output could not be written. The message names the file and what was wrong."""

    def __init__(self, path, message: str):
        self.path = str(path)
        self.message = message
        super().__init__(f"{self.path}: {message}")


def describe_os_error(e: OSError) -> str:
    """A short human reason for an OS error (``no space left on device``, ``read-only
    file system``, ``permission denied``...)."""
    if e.errno == errno.ENOSPC:
        return "no space left on device"
    if e.errno == errno.EROFS:
        return "read-only file system"
    if e.errno in (errno.EACCES, errno.EPERM):
        return "permission denied"
    if e.errno == errno.ENOENT:
        return "folder does not exist"
    if e.errno == errno.ENOTDIR:
        return "a part of the path is not a folder"
    if e.errno == errno.EISDIR:
        return "is a folder"
    return e.strerror or str(e)


def partial_path(path) -> Path:
    """Where an output is written while incomplete: ``<name>.part`` beside it."""
    p = Path(path)
    return p.with_name(p.name + PART_SUFFIX)


_INPUTS: dict[tuple[int, int], str] = {}  # (device, inode) -> path of the command's input files


def protect_inputs(paths) -> None:
    """Remember the files the running command reads (its recordings, profile, prior...):
    ``check_output_path``, and so every ``AtomicOutput``, refuses to write over one of them,
    however the path is spelled (links, relative paths). Replaces what was remembered."""
    _INPUTS.clear()
    for p in paths:
        try:
            st = os.stat(p)
        except (OSError, ValueError):
            continue
        if stat.S_ISREG(st.st_mode):
            _INPUTS[(st.st_dev, st.st_ino)] = str(p)


_KEEP_EXISTING: list = []  # non-empty: the running command replaces no existing output


def keep_existing_outputs(on: bool) -> None:
    """While on, ``check_output_path`` (and so every ``AtomicOutput``) refuses an output that
    already exists: the command line turns it on for the commands that write named outputs,
    unless ``--overwrite`` is given."""
    _KEEP_EXISTING.clear()
    if on:
        _KEEP_EXISTING.append(True)


def check_distinct_outputs(outputs: dict) -> None:
    """Refuse outputs of one command that are the same file (``outputs``: what -> path, None
    skipped): the last one written would replace the others (e.g. ``--summary`` naming the
    MCAP)."""
    seen: dict[str, tuple[str, object]] = {}
    for what, path in outputs.items():
        if path is None:
            continue
        key = os.path.realpath(path)
        if key in seen:
            other, other_path = seen[key]
            raise OutputError(path, f"the {what} and the {other} are the same file ({other_path})")
        seen[key] = (what, path)


def check_output_path(path, *, what: str = "output", updates: bool = False) -> Path:
    """Refuse, before any work, an output that cannot be written: the folder is missing or
    not a folder or not writable, the path (or its ``.part`` name) is a symbolic link, the path
    is a folder or a device, pipe or socket, or the name cannot be encoded for the file system;
    or it exists while ``keep_existing_outputs`` is on (``updates=True``: a record that is meant
    to be rewritten in place, such as a calibration store file, is exempt).
    Returns the path as a ``Path``."""
    p = Path(path)
    try:
        os.fsencode(p.name)
    except UnicodeError:
        raise OutputError(path, f"{what} file name cannot be encoded on this system") from None
    folder = p.parent if str(p.parent) else Path(".")
    if not folder.exists():
        raise OutputError(path, f"{what} folder {folder} does not exist")
    if not folder.is_dir():
        raise OutputError(path, f"{what} folder {folder} is not a folder")
    st: Optional[os.stat_result]
    mode: Optional[int]
    try:
        st = os.stat(p)
        mode = st.st_mode
    except OSError:
        st = mode = None  # not there yet (or a dangling link): created at commit
    source = None if st is None else _INPUTS.get((st.st_dev, st.st_ino))
    if source is not None:
        raise OutputError(path, f"{what} would overwrite the input {source}")
    if os.path.islink(p):
        where = "a missing file" if mode is None else (
            "a folder" if stat.S_ISDIR(mode) else not_a_file(mode) or "a file")
        raise OutputError(path, f"{what} path is a symbolic link (to {where}, "
                                f"{os.readlink(p)!r}); outputs never follow links: remove the "
                                "link or name its target")
    if mode is not None and stat.S_ISDIR(mode):
        raise OutputError(path, f"{what} path is a folder")
    part = partial_path(p)
    try:
        part_mode = os.lstat(part).st_mode
    except OSError:
        part_mode = None
    if part_mode is not None and not stat.S_ISREG(part_mode):
        what_part = "a symbolic link" if stat.S_ISLNK(part_mode) else (
            "a folder" if stat.S_ISDIR(part_mode) else not_a_file(part_mode) or "not a file")
        raise OutputError(part, f"is {what_part}, not a partial {what} of stillpoint; outputs "
                                "never follow links: remove it and run again")
    kind = None if mode is None else not_a_file(mode)
    if kind:
        raise OutputError(path, f"{what} path is {kind}, not a file (outputs are written "
                                "under a temporary name and renamed into place)")
    if mode is not None and _KEEP_EXISTING and not updates:
        raise OutputError(path, f"already exists (the {what}); add --overwrite to replace it")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise OutputError(path, f"{what} folder {folder} {_not_writable(folder)}")
    return p


def _not_writable(folder) -> str:
    """Why a folder ``os.access`` says cannot be written: a read-only file system (EROFS) or
    permissions (EACCES)."""
    try:
        if os.statvfs(folder).f_flag & getattr(os, "ST_RDONLY", 1):
            return "is read-only (on a read-only file system)"
    except (OSError, AttributeError):
        pass
    return "is read-only for this user (permission denied)"


def check_output_folder(folder, *, what: str = "output folder") -> Path:
    """Refuse, before any work, a destination folder that is missing, is not a folder, or is
    not writable. Returns it as a ``Path``."""
    p = Path(folder)
    try:
        mode = os.stat(p).st_mode
    except OSError as e:
        if e.errno in (errno.ENOENT, errno.ENOTDIR):
            raise OutputError(p, f"{what} does not exist") from None
        raise OutputError(p, f"{what} cannot be reached ({describe_os_error(e)})") from None
    if not stat.S_ISDIR(mode):
        raise OutputError(p, f"{what} is {not_a_file(mode) or 'a file'}, not a folder")
    if not os.access(p, os.W_OK | os.X_OK):
        raise OutputError(p, f"{what} {_not_writable(p)}")
    return p


def fsync_folder(folder) -> None:
    """Make a rename in ``folder`` durable (best effort where folders cannot be opened)."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


class AtomicOutput:
    """One output being written: ``fd``/``file`` point at ``<name>.part`` (locked); ``commit()``
    makes it ``<name>``; ``abandon()`` closes it and leaves the partial file (or removes it
    if nothing was written).

    ``binary=False`` opens a text file (UTF-8, ``newline=""`` so CSV writers control line
    ends)."""

    def __init__(self, path, *, binary: bool = True, what: str = "output",
                 updates: bool = False):
        self.path = check_output_path(path, what=what, updates=updates)
        self.part = partial_path(self.path)
        self.set_aside: Optional[Path] = None
        self.committed = False
        fd = self._create()
        self._ident = _identity(os.fstat(fd))
        self.fd = fd
        self.file = (os.fdopen(fd, "wb", buffering=0, closefd=False) if binary else
                     open(fd, "w", encoding="utf-8", newline="", closefd=False))

    def _busy(self) -> OutputError:
        return OutputError(self.path, "another stillpoint run is writing this output "
                                      f"({self.part.name} is locked)")

    def _new_part(self) -> int:
        """A new, empty ``.part`` file (O_EXCL: never a file or link that was there), locked."""
        try:
            fd = os.open(self.part, _NEW_PART, 0o644)
        except FileExistsError:
            raise
        except OSError as e:
            raise OutputError(self.part, f"cannot create: {describe_os_error(e)}") from None
        if fcntl is not None:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:  # pragma: no cover - a racing writer won the new name
                os.close(fd)
                raise self._busy() from None
        return fd

    def _create(self) -> int:
        try:
            return self._new_part()
        except FileExistsError:
            pass
        # a .part is there: another run's (locked), a killed run's (kept under a new name), an
        # empty leftover (removed), or something that is not our file (refused, left alone)
        try:
            st = os.lstat(self.part)
        except FileNotFoundError:  # gone meanwhile
            st = None
        if st is not None and not stat.S_ISREG(st.st_mode):
            what = "a symbolic link" if stat.S_ISLNK(st.st_mode) else (
                "a folder" if stat.S_ISDIR(st.st_mode) else not_a_file(st.st_mode) or "not a file")
            raise OutputError(self.part, f"is {what}, not a partial output of stillpoint; outputs "
                                         "never follow links: remove it and run again")
        if st is not None:
            try:
                fd = os.open(self.part, os.O_RDONLY | _NOFOLLOW | _CLOEXEC)
            except FileNotFoundError:
                fd = None
            except OSError as e:
                raise OutputError(self.part, f"cannot open: {describe_os_error(e)}") from None
            if fd is not None:
                try:
                    if _identity(os.fstat(fd)) != _identity(st):
                        raise self._busy()  # replaced between the two looks: someone is at work
                    if fcntl is not None:
                        try:
                            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                        except OSError:
                            raise self._busy() from None
                    if st.st_size > 0 or st.st_nlink > 1:  # a killed run's: keep it
                        self.set_aside = set_aside_name(self.part, st.st_mtime)
                        os.rename(self.part, self.set_aside)
                    else:  # an empty leftover
                        os.unlink(self.part)
                except OSError as e:
                    if isinstance(e, OutputError):
                        raise
                    raise OutputError(self.part, f"cannot set aside: {describe_os_error(e)}") from None
                finally:
                    os.close(fd)  # the lock on the old file ends; the new name is ours by O_EXCL
        try:
            return self._new_part()
        except FileExistsError:
            raise self._busy() from None

    def commit(self) -> Path:
        """Flush and fsync the partial file, rename it onto the final name, fsync the folder."""
        try:
            self.file.flush()
            os.fsync(self.fd)
        except OSError as e:
            self.abandon()
            raise OutputError(self.part, f"cannot finish writing: {describe_os_error(e)}; "
                                         "the partial file is kept") from None
        self.file.close()
        try:
            now = _identity(os.lstat(self.part))
        except OSError:
            now = None
        if now != self._ident:
            self.abandon(remove_if_empty=False)
            raise OutputError(self.part, "was replaced while it was written (not the file "
                                         f"stillpoint wrote); {self.path} is not changed")
        os.replace(self.part, self.path)
        fsync_folder(self.path.parent)
        os.close(self.fd)  # releases the lock after the rename: no window for a second writer
        self.fd = -1
        self.committed = True
        return self.path

    def abandon(self, *, remove_if_empty: bool = True) -> Optional[Path]:
        """Stop writing; the partial file stays (``None`` if it was empty and removed)."""
        if self.fd < 0:
            return None if self.committed else self.part
        try:
            self.file.close()
        except OSError:
            pass
        empty = False
        try:
            empty = os.fstat(self.fd).st_size == 0
        except OSError:
            pass
        if empty and remove_if_empty:
            try:
                os.unlink(self.part)
            except OSError:
                pass
        os.close(self.fd)
        self.fd = -1
        return None if (empty and remove_if_empty) else self.part


def _identity(st) -> tuple:
    return (st.st_dev, st.st_ino)


def set_aside_name(part, when: Optional[float] = None) -> Path:
    """``<name>.part.<UTC time>[-n]`` beside ``part`` (``when``: a POSIX time, default now), not
    taken by anything (links included): the name every writer's set-aside partial file gets."""
    stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime(when))
    aside = part.with_name(f"{part.name}.{stamp}")
    n = 1
    while os.path.lexists(aside):
        aside = part.with_name(f"{part.name}.{stamp}-{n}")
        n += 1
    return aside


@contextmanager
def atomic_output(path, *, binary: bool = True, what: str = "output",
                  updates: bool = False) -> Iterator[IO]:
    """``with atomic_output("x.csv", binary=False) as f: ...`` writes ``x.csv.part`` and renames
    it onto ``x.csv`` when the block ends without an exception. On an exception the partial
    file stays (removed if empty) and the exception propagates; OS errors while writing
    become an ``OutputError`` naming the partial file."""
    out = AtomicOutput(path, binary=binary, what=what, updates=updates)
    try:
        yield out.file
    except OSError as e:
        kept = out.abandon()
        if isinstance(e, StillpointError):
            raise
        where = f"; the partial file {kept} is kept" if kept else ""
        raise OutputError(path, f"{describe_os_error(e)}{where}") from None
    except BaseException:
        out.abandon()
        raise
    out.commit()
