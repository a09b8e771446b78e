"""Infant leg-movement counting (Smith et al. 2015 as in the Oh, Loeb & Smith 2024 reference
code): detector (``detect``), cycle filter / sleep / rate / kinematics (``post``), signals and
filters (``signals``), and the per-leg workflow (``leg.count_leg``).

    from stillpoint.engine.movements import count_leg
    left = count_leg("left.cwa", calibration=static_cal, variant="v2", filter="none")
"""

from .detect import Thresholds, detect_movements, thresholds
from .leg import LegResult, MovementInputError, count_leg, detect_signals
from .post import cycle_filter, kinematics, rate, sleep_samples

__all__ = ["count_leg", "detect_signals", "detect_movements", "thresholds", "Thresholds", "LegResult",
           "MovementInputError", "cycle_filter", "sleep_samples", "rate", "kinematics"]
