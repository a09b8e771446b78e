"""Simulator: free-living wearers, a sensor model of named effects, device clocks, and real
.cwa/.bin recordings with a ground-truth JSON.

Modules: ``model`` (effects, JSON model files, the pure deterministic sensor function),
``wearer`` (behaviour schedule and motion at a body site), ``temperature`` (device temperature),
``clock`` (RTC model), ``sensor`` (the full sensor incl. noise, clipping, quantisation),
``device`` (one device: tracks, chunks), ``truth`` (truth JSON, labels CSV), ``record``
(files through the writers, pairs), ``source`` (SimSource: the simulator as a
Source of Blocks, no file), ``corrupt`` (damaging .bin pages).
"""

from .model import (EFFECT_ORDER, EFFECTS, ModelError, SensorModel, apply_deterministic,
                    first_order_lag, ggir_equivalent, load_model, parse_effect_option,
                    resolve_model, save_model)
from .record import (DeviceSim, SimChunk, Truth, build_model, iter_chunks, load_labels, load_truth,
                     make_devices, relative_clock_s, simulate_pair, simulate_recording,
                     truth_device_time)
from .source import SimSource
from .temperature import TemperatureParams
from .wearer import SITES, WEARERS, WearerParams, wearer_params

__all__ = ["DeviceSim", "EFFECT_ORDER", "EFFECTS", "ModelError", "SITES", "SensorModel", "SimChunk", "SimSource",
           "TemperatureParams", "Truth", "WEARERS", "WearerParams", "apply_deterministic", "build_model",
           "first_order_lag", "ggir_equivalent", "iter_chunks", "load_labels", "load_model",
           "load_truth", "make_devices", "parse_effect_option", "relative_clock_s", "resolve_model", "save_model",
           "simulate_pair", "simulate_recording", "truth_device_time", "wearer_params"]
