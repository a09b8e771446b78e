"""Dev scripts reuse the test doubles that live under tests/ (a synthetic window-feature
recording with a known calibration error, a synthetic device pair with known clocks); they are
not part of the installed package. Importing this module puts the repository's tests/ folder on
``sys.path`` so a script can ``import synthetic_calibration`` / ``synthetic_alignment``."""

from __future__ import annotations

import sys
from pathlib import Path

TESTS = Path(__file__).resolve().parent.parent / "tests"
if not (TESTS / "synthetic_calibration.py").is_file():
    raise SystemExit(f"this dev script needs the repository's tests/ folder ({TESTS} not found)")
if str(TESTS) not in sys.path:
    sys.path.insert(0, str(TESTS))
