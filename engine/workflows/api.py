"""One call for the whole discrepancy workflow: input (recording, MCAP log, feature table or
WindowFeatures) + starting sensor model (the simulator's JSON; default offset + gain) -> report.

    from stillpoint.engine.workflows import analyse
    result, report = analyse("rec.cwa", model="start.json", out_dir="report/")
    report["steps"], report["final_model"]          # same keys as `stillpoint discrepancy --json`
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional, Union

from stillpoint.engine.sim import model as sim

from ..features import WindowFeatures
from . import discrepancy, report
from .inputs import SD_THRESHOLD_G, PreparedInput, load, prepare
from .simmodel import FITTED_EFFECTS, from_sim, noise_sd_mg

DEFAULT_START = {"offset": {}, "gain": {}}


def as_model(m) -> Optional[sim.SensorModel]:
    if m is None or isinstance(m, sim.SensorModel):
        return m
    if isinstance(m, dict):
        return sim.SensorModel.from_dict(m) if "effects" in m else sim.SensorModel(m)
    return sim.load_model(m)


def analyse(source: Union[str, Path, WindowFeatures, PreparedInput], model=None, truth=None,
            out_dir=None, folds: int = 5, max_steps: int = 8, effects=None,
            sd_threshold: float = SD_THRESHOLD_G, rate_hz: Optional[float] = None,
            plots: bool = True):
    """Run the workflow; returns (DiscrepancyResult, report dict). Writes the report files when
    ``out_dir`` is given."""
    if isinstance(source, PreparedInput):
        prepared = source
    elif isinstance(source, WindowFeatures):
        prepared = prepare(source, sd_threshold=sd_threshold)
    else:
        prepared = load(source, sd_threshold=sd_threshold)
    if rate_hz:
        prepared.rate_hz = float(rate_hz)
    start_sim = as_model(model) or sim.SensorModel(DEFAULT_START)
    truth_sim = as_model(truth)
    fitted_on = [e for e in start_sim.effects if e in FITTED_EFFECTS]
    if not fitted_on:
        start_sim = start_sim.with_effect("offset").with_effect("gain")
    start = from_sim(start_sim)
    noise = None
    noise_from = truth_sim if truth_sim is not None and truth_sim.on("noise") else start_sim
    if prepared.rate_hz:
        if not noise_from.on("noise") and prepared.device:
            # no noise term in the model: compare with the simulator's default for this device
            dev = prepared.device.lower()
            noise_from = sim.SensorModel({"noise": dict(zip(
                ("x_ug_per_rthz", "y_ug_per_rthz", "z_ug_per_rthz"),
                sim.DEFAULT_NOISE_UG.get(dev, sim.DEFAULT_NOISE_UG["ax3"])))})
        noise = noise_sd_mg(noise_from, prepared.rate_hz)
    res = discrepancy.run(prepared, start_model=start,
                          truth=None if truth_sim is None else from_sim(truth_sim),
                          folds=folds, max_steps=max_steps, effects=effects, noise_model_mg=noise)
    src = prepared.source
    if out_dir is not None:
        d = report.write(res, out_dir, carry=start_sim, source=src, truth=truth_sim, plots=plots)
    else:
        d = report.to_dict(res, carry=start_sim, source=src, truth=truth_sim)
    return res, d
