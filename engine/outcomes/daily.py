"""The activity outcome columns of the epoch and day tables, from one local day's epochs.

``OutcomeSettings``: a cut-point set of the registry (``cutpoints``, by key), GGIR bout lengths in
minutes and the bout criterion, whether to count steps. ``DailyOutcomes`` turns them into columns:

* epoch table: ``band_<key>`` (``sedentary``, ``light``, ``moderate`` or ``vigorous`` by the
  set's thresholds on its metric; ``below_moderate`` when the set has no light threshold; empty
  for an epoch that is not clean), ``steps_verisense_<set>`` (steps whose time falls in the
  epoch) and ``bouts_<key>`` (the GGIR bouts the epoch is in, e.g. ``moderate_1m;mvpa_1m;mvpa_5m``);
* day table, per band of the set (``light``, ``moderate``, ``vigorous``, ``mvpa`` = moderate and
  above): ``min_<band>_<key>`` (minutes of clean epochs with lower <= value < upper) and
  ``bout_min_<band>_<m>m_<key>`` (minutes in GGIR bouts of at least ``m`` minutes,
  ``engine.outcomes.bouts``); per step parameter set ``steps_verisense_<set>`` (steps in the day)
  and ``cadence_max_spm_verisense_<set>`` (most steps in one clock minute of the day); with
  ``impute``, the ``*_imputed`` columns of ``engine.outcomes.impute`` (GGIR's imputation).

Epochs that are not clean (nonwear, clipping, gap, QC, filter warm-up) never meet a band's
condition, as GGIR's bouts only see worn time.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .bouts import BOUT_CRITERION, ggir_bouts
from .cutpoints import CutPoints, lookup
from .steps import step_column
from .verisense import PARAMETER_SETS

BOUT_MINUTES = (1, 5, 10)  # GGIR params_phyact mvpadur / boutdur.mvpa defaults
BAND_ORDER = ("light", "moderate", "vigorous", "mvpa")
# day-table column prefixes of the outcome columns (collation reads them like the ENMO bands)
DAY_PREFIXES = ("min_light_", "min_moderate_", "min_vigorous_", "min_mvpa_", "bout_min_",
                "steps_", "cadence_max_spm_", "enmo_mean_mg_imputed", "mad_mean_mg_imputed",
                "m10_mg_imputed", "l5_mg_imputed")


@dataclass
class OutcomeSettings:
    cutpoints: str = ""  # registry key; "" = no band columns
    bout_minutes: tuple = BOUT_MINUTES
    bout_criterion: float = BOUT_CRITERION
    steps: tuple = ()  # Verisense parameter sets; () = no step columns
    impute: bool = False  # GGIR's nonwear imputation: *_imputed day columns (engine.outcomes.impute)

    @property
    def active(self) -> bool:
        return bool(self.cutpoints or self.steps or self.impute)

    def to_dict(self) -> dict:
        return {"cutpoints": self.cutpoints, "bout_minutes": list(self.bout_minutes),
                "bout_criterion": self.bout_criterion, "steps": list(self.steps),
                "impute": self.impute}


@dataclass
class DailyOutcomes:
    settings: OutcomeSettings
    epoch_s: float
    cut: CutPoints = field(init=False, default=None)

    def __post_init__(self):
        s = self.settings
        self.cut = lookup(s.cutpoints).scaled(self.epoch_s) if s.cutpoints else None
        if self.cut is not None and self.cut.counts and s.impute:
            raise ValueError("GGIR's imputation works on ENMO or MAD: not with a counts cut-point set")
        for name in s.steps:
            if name not in PARAMETER_SETS:
                raise ValueError(f"unknown Verisense parameter set {name!r}; known: "
                                 f"{', '.join(PARAMETER_SETS)}")
        self.epochs_per_minute = max(1, int(round(60.0 / self.epoch_s)))

    # ------------------------------------------------------------------ names
    def epoch_columns(self) -> list:
        out = [f"band_{self.cut.key}"] if self.cut else []
        out += [step_column(s) for s in self.settings.steps]
        return out + ([f"bouts_{self.cut.key}"] if self.cut else [])

    def day_columns(self) -> list:
        out = self.base_day_columns()
        if self.settings.impute:
            from .impute import imputed_columns
            out += imputed_columns(self)
        return out

    def base_day_columns(self) -> list:
        """The day columns computed from the day's own epochs (not the imputed ones)."""
        out = []
        if self.cut:
            bands = [b for b in BAND_ORDER if b in self.cut.bands()]
            out += [f"min_{b}_{self.cut.key}" for b in bands]
            out += [f"bout_min_{b}_{m:g}m_{self.cut.key}" for b in bands
                    for m in self.settings.bout_minutes]
        for s in self.settings.steps:
            out += [step_column(s), f"cadence_max_spm_{step_column(s)[len('steps_'):]}"]
        return out

    # ------------------------------------------------------------------ epochs
    def epoch_labels(self, values: np.ndarray, clean: np.ndarray) -> list:
        """The band of each epoch (empty when not clean or without a value)."""
        c = self.cut
        v = np.where(clean & np.isfinite(values), values, np.nan)
        lab = np.full(v.shape, "", dtype=object)
        ok = np.isfinite(v)
        low = "sedentary" if c.light is not None else "below_moderate"
        lab[ok] = low
        for name, lo in (("light", c.light), ("moderate", c.moderate), ("vigorous", c.vigorous)):
            if lo is not None:
                lab[ok & (v >= lo)] = name
        return lab.tolist()

    def epoch_bouts(self, values: np.ndarray, clean: np.ndarray) -> list:
        """For one local day's epochs: the bouts each epoch is in, ``<band>_<m>m`` joined by
        ``;`` (bands in the order light, moderate, vigorous, mvpa; lengths increasing)."""
        lab = np.full(values.shape[0], "", dtype=object)
        for b, m, inb in self._bouts(values, clean):
            lab[inb] = lab[inb] + f";{b}_{m:g}m"
        return [x[1:] for x in lab.tolist()]

    def _bouts(self, values: np.ndarray, clean: np.ndarray):
        """(band, minutes, epochs in bouts) of the set's bands and the bout lengths."""
        v = np.where(clean & np.isfinite(values), values, -np.inf)
        bands = self.cut.bands()
        for b in BAND_ORDER:
            if b not in bands:
                continue
            lo, hi = bands[b]
            mark = (v >= lo) & ((v < hi) if hi is not None else True)
            for m in self.settings.bout_minutes:
                yield b, m, ggir_bouts(mark, int(round(m * self.epochs_per_minute)),
                                       self.epochs_per_minute, self.settings.bout_criterion)

    # ------------------------------------------------------------------ one day
    def day(self, values: np.ndarray, clean: np.ndarray, start_ns: np.ndarray,
            steps: dict) -> dict:
        """Day-table values from the day's epochs (metric values, clean mask, starts) and
        per-epoch step counts ``{set: (k,) int}``."""
        row = {}
        if self.cut:
            v = np.where(clean & np.isfinite(values), values, -np.inf)
            for b, (lo, hi) in self.cut.bands().items():
                mark = (v >= lo) & ((v < hi) if hi is not None else True)
                row[f"min_{b}_{self.cut.key}"] = int(mark.sum()) * self.epoch_s / 60.0
            for b, m, inb in self._bouts(values, clean):
                row[f"bout_min_{b}_{m:g}m_{self.cut.key}"] = int(inb.sum()) * self.epoch_s / 60.0
        for s in self.settings.steps:
            n = np.asarray(steps.get(s, np.zeros(start_ns.shape[0], np.int64)))
            row[step_column(s)] = int(n.sum())
            minute = start_ns // (60 * 10**9)
            if n.shape[0]:
                _, inv = np.unique(minute, return_inverse=True)
                row[f"cadence_max_spm_{step_column(s)[len('steps_'):]}"] = int(
                    np.bincount(inv, weights=n).max())
            else:
                row[f"cadence_max_spm_{step_column(s)[len('steps_'):]}"] = 0
        return row
