"""The cut-point registry: published intensity thresholds, one row per population, device,
placement and metric, read from ``cutpoints.csv`` (package data).

Each row: ``key``, the publication (``authors``, ``year``, ``doi``, ``table``, ``page``),
``population`` and ``age_range``, ``device``, ``placement``, ``metric`` (``ENMO`` or ``MAD``, in mg;
``COUNTS_AXIS1`` or ``COUNTS_VM``, ActiLife counts of axis1 or of the vector magnitude per
``epoch_s`` of the publication: ``--counts`` must be on, and the thresholds are scaled to the run's
epoch by ``scaled``), ``epoch_s`` (when the publication's epoch is recorded), the lower edges of
``light``, ``moderate`` and ``vigorous`` (empty when the publication gives none), and
``transcribed_from``: where the values were read (the one place every threshold's source is named).
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Optional

REGISTRY = Path(__file__).with_name("cutpoints.csv")
# registry metric -> epoch-table column
METRICS = {"ENMO": "enmo_mg", "MAD": "mad_mg", "COUNTS_AXIS1": "axis1", "COUNTS_VM": "vm"}
COUNT_METRICS = ("COUNTS_AXIS1", "COUNTS_VM")  # counts per publication epoch: scaled to the run's


@dataclass(frozen=True)
class CutPoints:
    key: str
    authors: str
    year: int
    doi: str
    table: str
    page: str
    population: str
    age_range: str
    device: str
    placement: str
    metric: str
    epoch_s: Optional[float]
    light: Optional[float]
    moderate: Optional[float]
    vigorous: Optional[float]
    transcribed_from: str

    @property
    def column(self) -> str:
        """The epoch-table column the thresholds apply to."""
        return METRICS[self.metric]

    @property
    def counts(self) -> bool:
        """Thresholds on ActiLife counts (the run needs ``--counts``)."""
        return self.metric in COUNT_METRICS

    def scaled(self, epoch_s: float) -> "CutPoints":
        """The thresholds for epochs of ``epoch_s``: counts thresholds are per the publication's
        epoch (counts add up over time), mg thresholds are means and stay as they are."""
        if not self.counts:
            return self
        from dataclasses import replace
        f = float(epoch_s) / float(self.epoch_s)
        return replace(self, **{b: None if getattr(self, b) is None else getattr(self, b) * f
                                for b in ("light", "moderate", "vigorous")})

    def bands(self) -> dict:
        """Band name -> (lower, upper) mg; upper None is open. ``mvpa`` is moderate and above.
        Bands whose lower edge the publication does not give are left out."""
        out = {}
        if self.light is not None:
            out["light"] = (self.light, self.moderate)
        if self.moderate is not None:
            out["moderate"] = (self.moderate, self.vigorous)
            out["mvpa"] = (self.moderate, None)
        if self.vigorous is not None:
            out["vigorous"] = (self.vigorous, None)
        return out


def _num(text: str) -> Optional[float]:
    text = text.strip()
    return float(text) if text else None


@lru_cache(maxsize=1)
def registry() -> dict:
    """key -> CutPoints, in file order."""
    out = {}
    with open(REGISTRY, newline="", encoding="utf-8") as f:
        for r in csv.DictReader(f):
            out[r["key"]] = CutPoints(
                key=r["key"], authors=r["authors"], year=int(r["year"]), doi=r["doi"],
                table=r["table"], page=r["page"], population=r["population"],
                age_range=r["age_range"], device=r["device"], placement=r["placement"],
                metric=r["metric"], epoch_s=_num(r["epoch_s"]), light=_num(r["light"]),
                moderate=_num(r["moderate"]), vigorous=_num(r["vigorous"]),
                transcribed_from=r["transcribed_from"])
    return out


def lookup(key: str) -> CutPoints:
    """The row named ``key``; ValueError naming the known keys otherwise."""
    reg = registry()
    if key not in reg:
        raise ValueError(f"unknown cut-point set {key!r}; known: {', '.join(reg)}")
    return reg[key]
