"""``stillpoint replay --check`` on a run that computed sleep: the replay computes it too, with the
settings the run logged, so every topic (``/sleep/night`` and ``/sleep/sib`` included) is
identical and the check exits 0."""

from __future__ import annotations

import json

import pytest

from stillpoint.engine.mcap.compare import compare
from stillpoint.engine.mcap.stream import read_metadata
from stillpoint.engine.sim.record import simulate_recording
from stillpoint.tools.cli import main


@pytest.fixture(scope="module")
def rec(tmp_path_factory):
    d = tmp_path_factory.mktemp("replay_sleep")
    cwa = d / "p3.cwa"
    simulate_recording(cwa, days=2.0, hz=12.5, seed=4, truth_path=False, labels_path=False)
    return d, cwa


def _sleep_settings(mcap):
    with open(mcap, "rb") as f:
        meta = read_metadata(f)
    return json.loads(meta["summary"]["tables"])["sleep"]["settings"]


def test_replay_check_of_a_run_with_a_zone_exits_0(rec, capsys):
    d, cwa = rec
    mcap = d / "zoned.mcap"
    assert main(["process", str(cwa), "-o", str(mcap), "--timezone", "Europe/London",
                 "--hdcza-ignore-invalid", "na", "-q"]) == 0
    assert _sleep_settings(mcap)["HASPT_ignore_invalid"] is None  # the setting is in the log
    out = d / "zoned.replay.mcap"
    capsys.readouterr()
    code = main(["replay", str(mcap), "-o", str(out), "--check", "-q"])
    text = capsys.readouterr().out
    assert code == 0, text
    res = compare(mcap, out)
    for topic in ("/sleep/night", "/sleep/sib"):
        assert res[topic]["identical"] and res[topic]["messages"][0] > 0, (topic, res[topic])
    assert "/sleep/sib: identical" in text
    assert (d / "zoned.replay.nights.csv").read_text() == (d / "zoned.nights.csv").read_text()


def test_replay_of_a_run_without_a_zone_repeats_its_device_clock_nights(rec):
    d, cwa = rec
    mcap = d / "plain.mcap"
    assert main(["process", str(cwa), "-o", str(mcap), "-q"]) == 0
    out = d / "plain.replay.mcap"
    assert main(["replay", str(mcap), "-o", str(out), "--check", "-q"]) == 0
    res = compare(mcap, out)
    assert res["/sleep/night"]["identical"] and res["/sleep/night"]["messages"][0] > 0
    assert (d / "plain.replay.nights.csv").read_text() == (d / "plain.nights.csv").read_text()
