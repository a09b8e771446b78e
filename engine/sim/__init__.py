"""Simulator: free-living wearers, a sensor model of named effects, device clocks, and real
.cwa/.bin recordings with a ground-truth JSON.

Modules: ``model`` (effects, JSON model files, the pure deterministic sensor function),
``wearer`` (behaviour schedule and motion at a body site), ``temperature`` (device temperature),
``clock`` (RTC model), ``sensor`` (the full sensor incl. noise, clipping, quantisation),
``record`` (streaming generation, writers, truth).
"""

from .model import (EFFECT_ORDER, EFFECTS, ModelError, SensorModel, apply_deterministic,
                    first_order_lag, ggir_equivalent, load_model, parse_effect_option,
                    resolve_model, save_model)

__all__ = ["EFFECT_ORDER", "EFFECTS", "ModelError", "SensorModel", "apply_deterministic",
           "first_order_lag", "ggir_equivalent", "load_model", "parse_effect_option",
           "resolve_model", "save_model"]
