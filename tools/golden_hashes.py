"""Recompute the golden hashes of `process` (tests/golden.py) and rewrite
tests/data/golden_hashes.json; print which outputs changed.

    STILLPOINT_REAL_DATA=../shared/data/real python tools/golden_hashes.py [--check] [CASE ...]

Run it only for a deliberate change of output, and name that change in the commit that carries
the new JSON file (tests/project/test_golden_hashes.py says when regenerating is legitimate). ``--check``
compares without writing (exit 1 when anything differs). Real-file cases need STILLPOINT_REAL_DATA;
without it they keep their committed hashes.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

import golden  # noqa: E402  (tests/golden.py: the cases and the fingerprints)


def main(argv=None) -> int:
    """Recompute the chosen cases (default: all), print what changed, write the JSON file."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("cases", nargs="*", help="case names (default: all)")
    ap.add_argument("--check", action="store_true", help="compare only; write nothing")
    args = ap.parse_args(argv)
    names = {c.name for c in golden.CASES}
    unknown = sorted(set(args.cases) - names)
    if unknown:
        ap.error(f"unknown case(s) {', '.join(unknown)}; known: {', '.join(sorted(names))}")
    try:
        hashes = golden.load_hashes()
    except FileNotFoundError:
        hashes = {}
    changed = False
    with tempfile.TemporaryDirectory(prefix="stillpoint-golden-") as tmp:
        for case in golden.CASES:
            if args.cases and case.name not in args.cases:
                continue
            if case.needs_real_data and golden.real_data_dir() is None:
                print(f"{case.name}: skipped ({golden.REAL_DATA_ENV} not set; hashes kept)")
                continue
            got = golden.run_case(case, Path(tmp) / case.name)
            diff = golden.differences(hashes.get(case.name, {}), got)
            print(f"{case.name}: " + ("unchanged" if not diff else f"{len(diff)} changed"))
            for line in diff:
                print(line)
            changed |= bool(diff)
            hashes[case.name] = got
    for stale in sorted(set(hashes) - names):
        print(f"{stale}: no longer a case, removed")
        del hashes[stale]
        changed = True
    if args.check:
        return 1 if changed else 0
    golden.save_hashes(hashes)
    print(f"wrote {golden.HASHES_PATH}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
