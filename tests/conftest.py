"""Shared fixtures. Real-file conformance tests read STILLPOINT_REAL_DATA (set by .ci/run):
set -> a missing file is a failure; unset -> those tests skip with a visible reason."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

try:  # CI runs the property tests on a fixed set of examples so a green run is reproducible;
    # locally they explore new random examples each run.
    from hypothesis import settings as _hyp_settings

    _hyp_settings.register_profile("ci", derandomize=True, print_blob=True)
    if os.environ.get("CI"):
        _hyp_settings.load_profile("ci")
except ImportError:  # hypothesis is in the test extra; without it only the property tests fail
    pass

REAL_DATA_ENV = "STILLPOINT_REAL_DATA"

# the tests' cache of built tables (engine/core/cache.py) is their own, not the user's
if "STILLPOINT_CACHE_DIR" not in os.environ:
    import atexit
    import shutil
    import tempfile

    os.environ["STILLPOINT_CACHE_DIR"] = tempfile.mkdtemp(prefix="stillpoint-test-cache-")
    atexit.register(shutil.rmtree, os.environ["STILLPOINT_CACHE_DIR"], True)


@pytest.fixture(scope="session")
def real_data_dir() -> Path:
    value = os.environ.get(REAL_DATA_ENV)
    if not value:
        pytest.skip(f"{REAL_DATA_ENV} is not set: real-recording conformance tests skipped")
    d = Path(value)
    if not d.is_dir():
        pytest.fail(f"{REAL_DATA_ENV}={value} is not a directory")
    return d


def _files_in(folder: Path, what: str):
    """name -> Path in ``folder``; a missing file fails (never skips)."""

    def get(name: str) -> Path:
        p = folder / name
        if not p.is_file():
            pytest.fail(f"{what} {name} missing from {folder}")
        return p

    return get


@pytest.fixture(scope="session")
def real_file(real_data_dir):
    """real_file("name.cwa") -> Path; fails (never skips) when the file is missing."""
    return _files_in(real_data_dir, "real recording")


@pytest.fixture(scope="session")
def fuzz3(real_data_dir):
    """fuzz3("name") -> Path of a reliability campaign's reproducer, kept beside the real
    recordings (STILLPOINT_REAL_DATA/../fuzz3, README there); skipped and failed as they are."""
    return _files_in(real_data_dir.parent / "fuzz3", "reproducer")


@pytest.fixture(scope="session")
def fuzz4(real_data_dir):
    """fuzz4("name") -> Path of a resource-bounds campaign's reproducer, kept beside the real
    recordings (STILLPOINT_REAL_DATA/../fuzz4, README there); skipped and failed as they are."""
    return _files_in(real_data_dir.parent / "fuzz4", "reproducer")
