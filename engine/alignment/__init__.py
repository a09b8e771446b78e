"""Dual-device temporal alignment (Brønd et al. 2021, and beyond): estimate the clock offset,
drift, halts and temperature-driven drift between two recordings worn together from the
acceleration itself, and resample the second onto the first's clock.

Modules: ``signal`` (common-rate grid, activity signal), ``lags`` (per-block normalised
cross-correlation), ``fit`` (Brønd regression; robust fit with steps, temperature, CIs),
``apply`` (resampling onto the reference clock), ``operator`` (streaming over two sources,
batch and online), ``mcap_out`` (MCAP topics), ``plot`` (figure), ``synthetic`` (test pairs).
"""

from .fit import CannotAlign, ClockFit, Step
from .operator import AlignConfig, AlignmentResult, estimate_alignment, run_alignment

__all__ = ["AlignConfig", "AlignmentResult", "CannotAlign", "ClockFit", "Step",
           "estimate_alignment", "run_alignment"]
