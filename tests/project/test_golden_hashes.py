"""Golden hashes: `process` on a short simulated recording (batch and online, a zone so that sleep
runs) and on real files writes exactly the committed log messages, metadata records and tables
(tests/golden.py says what is hashed; tests/data/golden_hashes.json holds the hashes).

A redesign, speed-up or clean-up must keep every hash; a deliberate change of output regenerates
them with `python tools/golden_hashes.py` and names the change in its commit.
"""

from __future__ import annotations

import pytest

import golden

HASHES = golden.load_hashes()


def test_every_case_has_committed_hashes():
    assert sorted(HASHES) == sorted(c.name for c in golden.CASES), (
        "tests/data/golden_hashes.json and tests/golden.py name different cases; "
        "run `python tools/golden_hashes.py`")


@pytest.mark.parametrize("case", golden.CASES, ids=lambda c: c.name)
def test_process_output_matches_golden_hashes(case, tmp_path, request):
    if case.needs_real_data:
        request.getfixturevalue("real_data_dir")  # skips with its reason when the folder is unset
    got = golden.run_case(case, tmp_path / case.name)
    expected = HASHES[case.name]
    diff = golden.differences(expected, got)
    if "input" in [line.split(":")[0].strip() for line in diff] and case.real is None:
        diff.insert(0, "  (the simulated input itself changed: the simulator's output moved)")
    assert not diff, (f"`process` output of case {case.name} differs from the committed golden "
                      f"hashes:\n" + "\n".join(diff) + "\n" + golden.REGENERATE_HELP)
