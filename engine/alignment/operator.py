"""Streaming alignment operator over two sources: pass 1 estimates the clock model, pass 2
(``apply.aligned_chunks``) resamples the other device onto the reference clock.

``estimate_alignment(ref, other, config)`` reads both sources block by block, always from the one
whose grid is behind, so it holds at most one 1 h block (plus margins) of each device at the
common rate, the per-block lags (a few numbers per hour) and 60 s temperature bins. With
``on_estimate`` it is the online mode: the clock model is refitted after every block and handed
to the callback (the batch mode simply uses the last one).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Callable, Iterator, Optional

import numpy as np

from stillpoint.engine.core.blocks import DeviceInfo
from stillpoint.engine.core.jsonsafe import jsonable

from .fit import CannotAlign, ClockFit, TemperatureRegressor, fit_brond, fit_robust
from .lags import SUB_BLOCKS, BlockLag, LagEstimator
from .signal import (BLOCK_S, COMMON_RATE_HZ, MAX_LAG_SAMPLES, MIN_BLOCKS, TEMP_BIN_S,
                     GridResampler, TemperatureTrack)

METHODS = ("brond", "robust")
ROBUST_MAX_LAG_S = 600.0  # robust search window: a halt of up to ~9 min still correlates
ROBUST_MIN_BLOCKS = 12  # 2 h of active overlapping data in 10 min blocks
ROBUST_BLOCK_S = 600.0  # robust blocks: 10 min (drift smears a 1 h peak by up to 0.36 s/100 ppm;
#                         gait makes neighbouring peaks compete; 6x more lags per hour)


@dataclass
class AlignConfig:
    """Settings of the alignment (defaults: the paper's, except where the method says)."""

    method: str = "robust"  # "brond" (the paper) or "robust"
    rate: Optional[float] = COMMON_RATE_HZ  # None: the reference's native (nominal) rate
    block_s: Optional[float] = None  # default: 1 h (brond), 10 min (robust)
    max_lag_s: Optional[float] = None  # default: 1000 samples (brond), 600 s (robust)
    block_time: str = "start"  # brond: "start" (authors' code), "centre" or "centroid"
    subsample: Optional[bool] = None  # default: False for brond (integer lags), True for robust
    min_blocks: Optional[int] = None  # default: 4 (brond, 1 h blocks), 12 (robust, 10 min)
    temperature: bool = True  # robust: consider the crystal-temperature term
    detect_steps: bool = True  # robust: piecewise model around halts/restarts
    keep_correlograms: bool = True

    def __post_init__(self):
        if self.method not in METHODS:
            raise ValueError(f"unknown alignment method {self.method!r}; use one of {METHODS}")
        if self.block_time not in ("start", "centre", "centroid"):
            raise ValueError("block_time must be 'start', 'centre' or 'centroid'")

    @property
    def block_length_s(self) -> float:
        if self.block_s is not None:
            return float(self.block_s)
        return BLOCK_S if self.method == "brond" else ROBUST_BLOCK_S

    @property
    def min_valid_blocks(self) -> int:
        if self.min_blocks is not None:
            return int(self.min_blocks)
        return MIN_BLOCKS if self.method == "brond" else ROBUST_MIN_BLOCKS

    @property
    def max_lag(self) -> int:
        if self.max_lag_s is not None:
            return int(round(self.max_lag_s * self.rate))
        if self.method == "brond":  # +-1000 samples at 30 Hz = 33.3 s, at any rate
            return int(round(MAX_LAG_SAMPLES / COMMON_RATE_HZ * self.rate))
        return int(round(ROBUST_MAX_LAG_S * self.rate))

    @property
    def use_subsample(self) -> bool:
        return self.method == "robust" if self.subsample is None else bool(self.subsample)


@dataclass
class AlignmentResult:
    """Everything pass 1 found: the fit (or why there is none), the block table, provenance."""

    config: AlignConfig
    t0_ns: int  # reference's first sample: time 0 of every "s since t0" value
    ref_info: DeviceInfo
    other_info: DeviceInfo
    blocks: list[BlockLag]
    fit: Optional[ClockFit] = None
    reason: str = ""  # why not aligned
    ref_span_s: tuple[float, float] = (0.0, 0.0)
    other_span_s: tuple[float, float] = (0.0, 0.0)  # other's clock, s since t0
    temperature: Optional[TemperatureRegressor] = None
    samples_dropped: dict = field(default_factory=dict)
    gaps: dict = field(default_factory=dict)  # device -> [(start_s, end_s)] own clock, s since t0

    @property
    def ok(self) -> bool:
        return self.fit is not None

    def _gap_steps(self) -> list:
        """Sampling interruptions seen in the timestamps (a halt while the clock ran on, a
        restart): located to the sample on the reference clock. They leave no lag step."""
        out = []
        for dev, gaps in self.gaps.items():
            for a, b in gaps:
                if dev == "other" and self.fit is not None:  # to the reference clock
                    a = a - float(self.fit.offset_s(a))
                    b = b - float(self.fit.offset_s(b))
                out.append({"kind": "gap", "device": "reference" if dev == "ref" else "other",
                            "time_s": round(a, 3), "time_ns": int(self.t0_ns + round(a * 1e9)),
                            "window_s": [round(a, 3), round(b, 3)],
                            "duration_s": round(b - a, 3)})
        return sorted(out, key=lambda d: d["time_s"])

    def as_dict(self) -> dict:
        cfg = self.config
        rate = cfg.rate
        d: dict = {
            "aligned": self.ok,
            "method": cfg.method,
            "reference": _info_dict(self.ref_info),
            "other": _info_dict(self.other_info),
            "t0_ns": int(self.t0_ns),
            "rate_hz": rate,
            "block_s": cfg.block_length_s,
            "max_lag_samples": cfg.max_lag,
            "sign": "offset = other-device clock minus reference clock; aligned other time = "
                    "reference time + offset",
        }
        fit = self.fit
        if fit is None:
            d.update({"reason": self.reason, "model": None, "initial_offset_s": None,
                      "drift_s_per_day": None, "drift_day7_s": None, "rmse_samples": None,
                      "steps": [], "blocks_used": 0,
                      "blocks_excluded": 0, "excluded_blocks": []})
        else:
            excl = [int(i) for i, inc in zip(fit.block_index, fit.included) if not inc]
            d.update({
                "model": fit.model,
                "initial_offset_s": fit.initial_offset_s,
                "drift_s_per_day": fit.drift_s_per_day,
                "drift_day7_s": fit.drift_day7_s,
                "drift_day7_clock_s": fit.drift_s_per_day * 7,
                "blocks_used": int(fit.included.sum()),
                "blocks_excluded": len(excl),
                "excluded_blocks": excl,
                "rmse_samples": fit.rmse,
                "rmse_s": fit.rmse / rate,
                "steps": ([dict(s.as_dict(rate, self.t0_ns), kind="lag_step") for s in fit.steps]
                          + self._gap_steps()),
                "temperature_coef_samples_per_c2s": fit.temp_coef or None,
                "ci": fit.ci(),
                "iterations": fit.iterations,
                "thresholds": fit.thresholds,
                "diagnostics": jsonable(fit.diagnostics),
            })
        d["blocks_total"] = len(self.blocks)
        d["blocks_valid"] = sum(1 for b in self.blocks if b.valid)
        d["block_lags"] = [b.as_dict(rate) for b in self.blocks]
        d["reference_span_s"] = list(self.ref_span_s)
        d["other_span_s"] = list(self.other_span_s)
        if any(self.samples_dropped.values()):
            d["samples_dropped_nonincreasing_time"] = self.samples_dropped
        return jsonable(d)


def _info_dict(info: DeviceInfo) -> dict:
    return {"device_type": info.device_type, "device_id": info.device_id,
            "session_id": info.session_id, "sample_rate_nominal": info.sample_rate_nominal,
            "path": info.path}



def fit_blocks(blocks: list[BlockLag], config: AlignConfig,
               temperature: Optional[TemperatureRegressor] = None) -> ClockFit:
    if config.method == "brond":
        return fit_brond(blocks, config.rate, config.block_time, config.min_valid_blocks)
    return fit_robust(blocks, config.rate, temperature if config.temperature else None,
                      config.min_valid_blocks, config.detect_steps)


def _temperature_regressor(tr: TemperatureTrack, to: TemperatureTrack, end_s: float
                           ) -> Optional[TemperatureRegressor]:
    if not len(tr) or not len(to):
        return None
    nb = int(np.ceil(max(end_s, TEMP_BIN_S) / TEMP_BIN_S)) + 1
    centres = (np.arange(nb) + 0.5) * TEMP_BIN_S
    return TemperatureRegressor.from_temperatures(centres, tr.series(0, nb), to.series(0, nb))


def estimate_alignment(reference, other, config: Optional[AlignConfig] = None,
                       on_block: Optional[Callable[[BlockLag], None]] = None,
                       on_estimate: Optional[Callable[[ClockFit, BlockLag], None]] = None
                       ) -> AlignmentResult:
    """Pass 1 over two Sources (see module doc). Never raises CannotAlign: an unalignable pair
    returns a result with ``fit=None`` and a ``reason``."""
    config = config or AlignConfig()
    it_ref: Iterator = iter(reference)
    it_oth: Iterator = iter(other)
    first = None
    for b in it_ref:
        if b.n:
            first = b
            break
    if first is None:
        return AlignmentResult(config, 0, reference.info, other.info, [],
                               reason="the reference recording has no samples")
    t0_ns = int(first.time_ns[0])
    if config.rate is None:
        config = replace(config, rate=float(reference.info.sample_rate_nominal))
    rs = {"ref": GridResampler(t0_ns, config.rate, reference.info.sample_rate_nominal),
          "other": GridResampler(t0_ns, config.rate, other.info.sample_rate_nominal)}
    temps = {"ref": TemperatureTrack(), "other": TemperatureTrack()}
    est = LagEstimator(config.rate, config.block_length_s, config.max_lag,
                       centred=config.method != "brond",
                       subsample=config.use_subsample,
                       sub_blocks=SUB_BLOCKS if config.block_length_s > 1200 else 0,
                       keep_correlograms=config.keep_correlograms)
    refit_every = max(1, int(round(3600.0 / config.block_length_s)))
    iters = {"ref": it_ref, "other": it_oth}
    pending = {"ref": first, "other": None}  # each stream's next non-empty block, read ahead
    blocks: list[BlockLag] = []
    last_fit: Optional[ClockFit] = None

    def handle(new: list[BlockLag]):
        nonlocal last_fit
        for bl in new:
            blocks.append(bl)
            if on_block is not None:
                on_block(bl)
            if on_estimate is not None and bl.valid and (
                    sum(1 for b in blocks if b.valid) % refit_every == 0):
                try:
                    last_fit = fit_blocks(blocks, config)
                except CannotAlign:
                    continue
                on_estimate(last_fit, bl)

    def upcoming(which):
        if pending[which] is None:
            blk = next(iters[which], None)
            while blk is not None and blk.n == 0:
                blk = next(iters[which], None)
            pending[which] = blk
        return pending[which]

    # the two streams are merged by time: the next block read is the one that starts first, so
    # a stream is never fed far past what the other has reached (a recording that starts a
    # year after the other would otherwise be NaN-filled across the whole year before either
    # could be compared)
    while not est.done:
        nxt = {}
        for which in ("ref", "other"):
            if not est.finished(which):
                blk = upcoming(which)
                if blk is None:
                    handle(est.finish(which))
                else:
                    nxt[which] = blk
        if not nxt:
            continue
        which = min(nxt, key=lambda w: int(nxt[w].time_ns[0]))  # a tie: the reference first
        blk = nxt[which]
        pending[which] = None
        temps[which].push_block(blk, t0_ns)
        for k0, vals in rs[which].push(blk):
            handle(est.feed(which, k0, vals))
    span = lambda r: (r.first_time_s or 0.0, r.last_time_s or 0.0)  # noqa: E731
    res = AlignmentResult(config, t0_ns, reference.info, other.info, blocks,
                          ref_span_s=span(rs["ref"]), other_span_s=span(rs["other"]),
                          samples_dropped={k: r.samples_dropped for k, r in rs.items()},
                          gaps={k: list(r.gaps) for k, r in rs.items()})
    if rs["other"].first_time_s is None:
        res.reason = "the other recording has no samples"
        return res
    lo = max(res.ref_span_s[0], res.other_span_s[0])
    hi = min(res.ref_span_s[1], res.other_span_s[1])
    if hi <= lo:
        res.reason = ("the recordings do not overlap in time (reference "
                      f"{res.ref_span_s[0]:.0f}-{res.ref_span_s[1]:.0f} s, other "
                      f"{res.other_span_s[0]:.0f}-{res.other_span_s[1]:.0f} s after the "
                      "reference start, each on its own clock)")
        return res
    res.temperature = _temperature_regressor(temps["ref"], temps["other"], res.ref_span_s[1])
    try:
        res.fit = fit_blocks(blocks, config, res.temperature)
    except CannotAlign as e:
        res.reason = e.reason
    return res


def run_alignment(open_reference: Callable[[], object], open_other: Callable[[], object],
                  config: Optional[AlignConfig] = None, out_mcap=None,
                  interpolation: str = "previous", out_rate: Optional[float] = None,
                  online: bool = False) -> AlignmentResult:
    """Batch alignment of two recordings (two passes, bounded memory).

    ``open_reference`` / ``open_other`` return a fresh Source each call (the other recording is
    read twice: once to estimate, once to resample). With ``out_mcap`` the block lags, the
    estimate(s) and, when aligned, the other device resampled onto the reference clock are
    written there (``online=True`` also logs the estimate refreshed after every valid block)."""
    from .apply import aligned_chunks
    from .mcap_out import TOPIC_BLOCK_LAG, TOPIC_ESTIMATE, AlignmentMcap

    config = config or AlignConfig()
    t0 = {"ns": 0}
    ref, oth = open_reference(), open_other()
    if config.rate is None:
        config = replace(config, rate=float(ref.info.sample_rate_nominal))
    sink = None
    try:
        sink = AlignmentMcap(out_mcap) if out_mcap is not None else None

        def on_block(bl: BlockLag):
            if sink is not None:
                sink.write_json(TOPIC_BLOCK_LAG, t0["ns"] + int(bl.start_s * 1e9),
                                bl.as_dict(config.rate))

        def on_estimate(fit: ClockFit, bl: BlockLag):
            if sink is not None:
                sink.write_json(TOPIC_ESTIMATE, t0["ns"] + int((bl.start_s + bl.duration_s) * 1e9),
                                {"final": False, "model": fit.model, "block": bl.index,
                                 "initial_offset_s": fit.initial_offset_s,
                                 "drift_s_per_day": fit.drift_s_per_day,
                                 "drift_day7_s": fit.drift_day7_s,
                                 "blocks_used": int(fit.included.sum()),
                                 "rmse_samples": fit.rmse})

        # t0 is only known once the reference's first block is read: peek it
        first = _peek_t0(ref)
        t0["ns"] = first[1]
        res = estimate_alignment(first[0], oth, config, on_block=on_block,
                                 on_estimate=on_estimate if online else None)
    except BaseException:
        if sink is not None:
            sink.abort()
        raise
    finally:
        _close(ref)
        _close(oth)
    if sink is None:
        return res
    try:
        end_ns = res.t0_ns + int(res.ref_span_s[1] * 1e9)
        sink.write_metadata("reference", _info_dict(res.ref_info))
        sink.write_metadata("other", _info_dict(res.other_info))
        if res.ok:
            src = open_other()
            try:
                for tns, acc in aligned_chunks(src, res.fit, res.t0_ns, out_rate, interpolation,
                                               start_s=0.0, end_s=res.ref_span_s[1]):
                    sink.write_aligned(tns, acc)
            finally:
                _close(src)
        final = res.as_dict()
        final["final"] = True
        final["interpolation"] = interpolation
        sink.write_json(TOPIC_ESTIMATE, end_ns, final)
        sink.write_metadata("alignment", final)
    except BaseException as e:
        kept = sink.abort()  # the partial log stays, recoverable; it is never finished half-done
        if kept is not None:
            try:
                e.partial_output = str(kept)
            except AttributeError:
                pass
        raise
    sink.close()
    return res


def _peek_t0(src):
    it = iter(src)
    for b in it:
        if b.n:
            class _Rest:
                info = src.info
                qc = getattr(src, "qc", None)

                def __iter__(self_inner):
                    yield b
                    yield from it

                def close(self_inner):
                    _close(src)
            return _Rest(), int(b.time_ns[0])
    return src, 0


def _close(src):
    close = getattr(src, "close", None)
    if close is not None:
        close()
