"""Count one leg's movements in a recording: calibrate (static six-orientation calibration of the
same device, or none), build the signals, detect, cycle-filter, estimate sleep and the rate.

``count_leg(path, calibration=None, variant="v2", filter="none", resample_hz=None,
accel_only=False, timing="real") -> LegResult``. Two legs are two independent calls, each with its
own device's calibration. ``timing="nominal"`` is the reference's arithmetic (samples / nominal
rate); the default turns samples into time with the recording's effective rate (timestamps).
AX3 and GENEActiv have no gyroscope: refused unless ``accel_only`` (gate always open; results
labelled not validated).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

import numpy as np

from stillpoint.engine.core.errors import StillpointError

import stillpoint.engine.movements.detect as D  # noqa: N812
from . import post as P
from .signals import DEG_TO_RAD, FILTERS, LegSignals, apply_filter, detrend, read_signals


class MovementInputError(StillpointError):
    """The recording cannot be used for movement counting (the message says why)."""


@dataclass
class LegResult:
    path: str
    device_key: str
    variant: str
    filter: str
    fs: int
    timing: str
    accel_only: bool
    thresholds: dict
    movements: np.ndarray  # (m, 3) start, second crossing, end (sample indices)
    time_ns: np.ndarray  # (m, 3) the same as times
    duration_s: np.ndarray
    average_ms2: np.ndarray
    peak_ms2: np.ndarray
    removed_by_cycle_filter: int
    candidates: int
    sleep_samples: int
    rate: P.Rate
    samples: int
    effective_rate_hz: float
    calibration: dict
    flags: list = field(default_factory=list)

    @property
    def count(self) -> int:
        return int(self.movements.shape[0])

    def summary(self) -> dict:
        r = self.rate
        return {"file": self.path, "device": self.device_key, "variant": self.variant,
                "filter": self.filter, "fs_hz": self.fs, "timing": self.timing,
                "effective_rate_hz": self.effective_rate_hz, "samples": self.samples,
                "accel_only": self.accel_only,
                "validated": not self.accel_only,
                "threshold_positive_ms2": self.thresholds["positive"],
                "threshold_negative_ms2": self.thresholds["negative"],
                "peaks_positive": self.thresholds["peaks_positive"],
                "peaks_negative": self.thresholds["peaks_negative"],
                "count": self.count, "candidates": self.candidates,
                "removed_by_cycle_filter": self.removed_by_cycle_filter,
                "recording_hours": r.recording_hours, "sleep_hours": r.sleep_hours,
                "awake_hours": r.awake_hours, "rate_per_hour_awake": r.per_hour_awake,
                "median_duration_s": _median(self.duration_s),
                "median_average_ms2": _median(self.average_ms2),
                "median_peak_ms2": _median(self.peak_ms2),
                "calibration": self.calibration, "flags": self.flags + r.flags}

    def rows(self) -> list:
        """One dict per movement (the CSV)."""
        out = []
        for i in range(self.count):
            s, c, e = (int(x) for x in self.movements[i])
            out.append({"start_index": s, "second_crossing_index": c, "end_index": e,
                        "start_ns": int(self.time_ns[i, 0]), "end_ns": int(self.time_ns[i, 2]),
                        "duration_s": float(self.duration_s[i]),
                        "average_ms2": float(self.average_ms2[i]),
                        "peak_ms2": float(self.peak_ms2[i])})
        return out


def _median(x):
    return float(np.median(x)) if len(x) else None


def detect_signals(sig: LegSignals, *, variant: str = "v2", filter: str = "none",
                   accel_only: bool = False, timing: str = "real", where: str = "",
                   strict_gyro: bool = False) -> dict:
    """Detector + post-processing on LegSignals (pure; ``count_leg`` wraps it with file I/O)."""
    if filter not in FILTERS:
        raise ValueError(f"filter must be one of {FILTERS}")
    if timing not in ("real", "nominal"):
        raise ValueError("timing must be 'real' or 'nominal'")
    n = sig.n
    if n < 3:
        raise MovementInputError(f"{where}: the recording holds no usable samples ({n})")
    if sig.fs <= 0:
        raise MovementInputError(f"{where}: the header gives no sample rate")
    try:
        a = apply_filter(detrend(sig.acc_norm), filter, sig.fs)
    except ValueError as e:
        raise MovementInputError(f"{where}: --filter {filter}: {e}") from None
    w = None
    if not accel_only:
        w = detrend(sig.gyro_norm)
        w *= DEG_TO_RAD
    mv, th = D.detect_movements(a, w, sig.fs, variant)
    if not th.usable:
        raise MovementInputError(
            f"{where}: no acceleration peaks between {D.PEAK_MIN_MS2} and {D.PEAK_REJECT_MS2} m/s^2 "
            f"({th.peaks_positive} positive, {th.peaks_negative} negative): no movement to set the "
            "thresholds from (an empty, still or sleep-only recording?)")
    gated = 0
    if strict_gyro and w is not None and mv.shape[0]:
        # the paper's wording: rotation (w > 0) on every sample of the movement, not only at the
        # samples the reference checks
        c = np.concatenate(([0], np.cumsum(w <= 0)))
        ok = (c[mv[:, 2] + 1] - c[mv[:, 0]]) == 0
        gated = int((~ok).sum())
        mv = mv[ok]
    kept, dropped = P.cycle_filter(mv, sig.fs)
    sleep = P.sleep_samples(kept, n, sig.fs)
    span_s = (int(sig.time_ns[-1]) - int(sig.time_ns[0])) / 1e9
    eff = (n - 1) / span_s if span_s > 0 else float(sig.fs)
    fs_time = float(sig.fs) if timing == "nominal" else eff
    rate = P.rate(kept.shape[0], n, sleep, fs_time)
    if rate.awake_hours <= 0:
        raise MovementInputError(f"{where}: the whole recording is sleep/inactive "
                                 f"({kept.shape[0]} movements): no awake time to rate")
    tsec = None if timing == "nominal" else (sig.time_ns - sig.time_ns[0]) / 1e9
    dur, avg, peak = P.kinematics(a, kept, tsec, fs_time)
    return {"a": a, "w": w, "thresholds": th, "movements": kept, "candidates": int(mv.shape[0]),
            "removed": int(dropped.sum()), "removed_by_strict_gyro": gated, "sleep": sleep, "rate": rate, "duration": dur,
            "average": avg, "peak": peak, "effective_rate_hz": eff}


def count_leg(path, calibration=None, *, variant: str = "v2", filter: str = "none",
              resample_hz=None, accel_only: bool = False, timing: str = "real",
              full_matrix: Optional[bool] = None, keep_signals: bool = False,
              strict_gyro: bool = False):
    """Count movements in one leg's recording (module docstring). ``calibration``: a
    ``StaticCalibration`` (or None: raw readings, flagged). Returns LegResult (and the signals
    when ``keep_signals``)."""
    from stillpoint.engine.recordings import open_recording
    path = Path(path)
    src = open_recording(path)
    info = src.info
    src.close()
    where = str(path)
    flags = []
    has_gyro = bool(info.gyro_range_dps) and "gyro_x" in info.channels
    if not has_gyro and not accel_only:
        raise MovementInputError(
            f"{where}: a {info.device_type} recording has no gyroscope; the detector needs the "
            "angular-velocity gate (AX6). Use the accel-only variant (not validated) to run anyway")
    if accel_only:
        flags.append("accel-only variant: gyro gate always open; NOT VALIDATED")
    cal_info: dict = {"applied": False}
    if calibration is not None:
        if calibration.device_key and calibration.device_key != info.device_key:
            raise MovementInputError(
                f"{where}: the calibration is for device {calibration.device_key}, the recording "
                f"is from {info.device_key}; each leg needs its own device's calibration")
        correct = (lambda g: calibration.apply(g, full_matrix=full_matrix))
        cal_info = {"applied": True, "device_key": calibration.device_key, "mode": calibration.mode,
                    "full_matrix": bool(full_matrix if full_matrix is not None
                                        else calibration.full_matrix),
                    "calibration_time": calibration.to_dict().get("calibration_time"),
                    "offset_g": list(calibration.offset_g), "gain": list(calibration.gain)}
    else:
        correct = (lambda g: g)
        flags.append("uncalibrated: raw readings (no static calibration given)")
    sig = read_signals(path, correct, resample_hz=resample_hz, use_gyro=not accel_only)
    if sig.n == 0:
        raise MovementInputError(f"{where}: the recording holds no samples")
    if calibration is not None and calibration.calibration_time_ns is not None:
        gap_h = (int(sig.time_ns[0]) - int(calibration.calibration_time_ns)) / 3.6e12
        cal_info["gap_hours"] = gap_h
    res = detect_signals(sig, variant=variant, filter=filter, accel_only=accel_only,
                         timing=timing, where=where, strict_gyro=strict_gyro)
    if strict_gyro:
        flags.append(f"strict gyro gate (w > 0 on every sample of a movement): "
                     f"{res['removed_by_strict_gyro']} candidate(s) removed")
    mv = res["movements"]
    th = res["thresholds"]
    out = LegResult(
        path=where, device_key=info.device_key, variant=variant, filter=filter, fs=sig.fs,
        timing=timing, accel_only=accel_only,
        thresholds={"positive": th.positive, "negative": th.negative,
                    "peaks_positive": th.peaks_positive, "peaks_negative": th.peaks_negative},
        movements=mv, time_ns=sig.time_ns[mv] if mv.size else np.zeros((0, 3), np.int64),
        duration_s=res["duration"], average_ms2=res["average"], peak_ms2=res["peak"],
        removed_by_cycle_filter=res["removed"], candidates=res["candidates"],
        sleep_samples=res["sleep"], rate=res["rate"], samples=sig.n,
        effective_rate_hz=res["effective_rate_hz"], calibration=cal_info, flags=flags)
    if keep_signals:
        return out, sig, res
    return out
