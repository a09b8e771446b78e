"""Ground truth of a simulated recording: the truth JSON (``Truth``, ``load_truth``), the clock
mapping helpers, and the per-10 s-window label CSV (``LABEL_COLUMNS``, ``write_labels``,
``load_labels``)."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

import numpy as np

from ..core.times import iso_local
from .model import ModelError, SensorModel, _jsonable
from .wearer import ACTIVITIES, MOTIONS, POSTURES

WINDOW_S = 10.0  # label windows
TRUTH_FORMAT = "stillpoint.sim_truth"


@dataclass
class Truth:
    """Everything the simulation knows; ``to_dict`` is the truth JSON."""

    path: Optional[str]
    device: dict
    site: str
    seed: int
    start_ns: int
    duration_s: float
    rate_hz_nominal: float
    rate_hz_true: float
    sensor_model: SensorModel
    clock: dict
    wearer: dict
    temperature: dict
    samples_written: int = 0
    corrupt_sectors: list = field(default_factory=list)
    labels_path: Optional[str] = None
    truth_path: Optional[str] = None
    summary: dict = field(default_factory=dict)
    pair: Optional[dict] = None

    def to_dict(self) -> dict:
        return _jsonable({
            "format": TRUTH_FORMAT, "version": 1, "path": self.path, "device": self.device,
            "site": self.site, "seed": self.seed, "start_ns": self.start_ns,
            "start_utc": _iso(self.start_ns), "duration_s": self.duration_s,
            "rate_hz_nominal": self.rate_hz_nominal, "rate_hz_true": self.rate_hz_true,
            "samples_written": self.samples_written, "sensor_model": self.sensor_model.to_dict(),
            "clock": self.clock, "corrupt_sectors": self.corrupt_sectors,
            "labels": {"path": self.labels_path, "window_s": WINDOW_S,
                       "columns": list(LABEL_COLUMNS), "activities": list(ACTIVITIES),
                       "postures": list(POSTURES), "motions": list(MOTIONS)},
            "wearer": self.wearer, "temperature": self.temperature, "summary": self.summary,
            "pair": self.pair})

    def to_json_text(self) -> str:
        return json.dumps(self.to_dict(), indent=1) + "\n"

    def save(self, path) -> None:
        """Write the truth JSON atomically (``<path>.part``, then renamed)."""
        from stillpoint.engine.core.outputs import atomic_output
        with atomic_output(path, binary=False, what="truth") as f:
            f.write(self.to_json_text())

    @property
    def labels(self) -> Optional[dict]:
        """Per-window labels as arrays (read from the labels CSV; kept in memory when no truth
        files were written)."""
        if getattr(self, "_labels", None) is None and self.labels_path:
            self._labels = load_labels(self.labels_path)
        return getattr(self, "_labels", None)


def _iso(ns: int) -> str:
    return iso_local(ns, 0, "us")


def load_truth(path) -> dict:
    """The truth JSON as a dict (``sensor_model`` is loadable with SensorModel.from_dict)."""
    d = json.loads(Path(path).read_text())
    if d.get("format") != TRUTH_FORMAT:
        raise ModelError(f"{path}: not a simulator truth file")
    return d


def truth_device_time(truth: dict, true_s) -> np.ndarray:
    """Device clock (ns since the epoch) at true times (s since the start), from a truth dict."""
    c = truth["clock"]
    t = np.asarray(true_s, np.float64)
    d = t + np.interp(t, np.asarray(c["table"]["true_s"]), np.asarray(c["table"]["device_minus_true_s"]))
    return truth["start_ns"] + np.round(d * 1e9).astype(np.int64)


def relative_clock_s(truth_a: dict, truth_b: dict, true_s) -> np.ndarray:
    """Device B's clock minus device A's clock (s) at true times (s since the common start): the
    lag an alignment method should find between two devices of a pair (truth dicts)."""
    return (truth_device_time(truth_b, true_s) - truth_device_time(truth_a, true_s)) / 1e9


LABEL_COLUMNS = ("window", "true_start_s", "device_start_ns", "samples", "still", "activity",
                 "posture", "motion", "temperature_c", "accel_temperature_c", "true_mean_x",
                 "true_mean_y", "true_mean_z", "true_sd_x", "true_sd_y", "true_sd_z")


def load_labels(path) -> dict:
    """Per-window labels CSV -> dict of numpy arrays (columns as in LABEL_COLUMNS)."""
    with open(path) as f:
        header = f.readline().strip().split(",")
    data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    out = {}
    for i, name in enumerate(header):
        col = data[:, i]
        out[name] = col.astype(np.int64) if name in ("window", "device_start_ns", "samples", "still",
                                                      "activity", "posture", "motion") else col
    return out


def write_labels(path, labels: dict) -> None:
    """Labels CSV: integer columns as integers, others with 6 decimals (nan for empty windows)."""
    from stillpoint.engine.core.outputs import atomic_output
    with atomic_output(path, binary=False, what="labels") as f:
        f.write(",".join(LABEL_COLUMNS) + "\n")
        _write_label_rows(f, labels)


def _write_label_rows(f, labels: dict, rows_per_block: int = 4096) -> None:
    cols = list(LABEL_COLUMNS)
    ints = {"window", "device_start_ns", "samples", "still", "activity", "posture", "motion"}
    # one %-format per row: "%d" of a Python int is its str(), "%.6f" of a float is what
    # np.char.mod("%.6f") gives (nan -> "nan")
    row_fmt = ",".join("%d" if c in ints else "%.6f" for c in cols) + "\n"
    n = labels[cols[0]].shape[0]
    for a in range(0, n, rows_per_block):
        b = min(n, a + rows_per_block)
        values = [labels[c][a:b].astype(np.int64 if c in ints else np.float64).tolist() for c in cols]
        f.write("".join([row_fmt % row for row in zip(*values)]))
