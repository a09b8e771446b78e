"""Log a static calibration and per-leg movement counts to MCAP through the one writer path
(``engine.mcap.log.McapLog``; spec static-calibration.md §5.6).

Topics (JSON):
* ``/static_calibration`` - the static estimate of a device (schema
  ``stillpoint.StaticCalibrationEstimate``: offset/scale in the engine form, ``extra.static``
  the whole result: offsets, gains, misalignment, noise, every window with band and length, the
  search attempts, warnings);
* ``/movements/<leg>/parameters`` - detection parameters (variant, thresholds, fs, filter,
  gyro gate, timing, calibration applied and its gap to the recording);
* ``/movements/<leg>/events`` - one message per movement at its start time (start, second
  crossing and end as samples and times, duration, average and peak |a|);
* ``/movements/<leg>/summary`` - count, sleep, awake hours, rate.
"""

from __future__ import annotations

from typing import Optional

from stillpoint.engine.mcap.jsonschemas import STATIC_CALIBRATION


def log_static_calibration(log, cal, log_time_ns: Optional[int] = None) -> None:
    """One ``/static_calibration`` message (at the calibration's first sample)."""
    d = cal.to_estimate().to_dict()
    d["positions"] = sum(1 for f in cal.faces.values() if f.get("samples"))
    t = log_time_ns if log_time_ns is not None else (cal.calibration_time_ns or 0)
    log.write_json("/static_calibration", int(t), d, schema=STATIC_CALIBRATION)


def log_leg(log, label: str, leg, calibration=None) -> None:
    """Parameters, one event per movement and the summary of one leg (a ``LegResult``)."""
    s = leg.summary()
    t0 = int(leg.time_ns[0, 0]) if leg.count else 0
    if calibration is not None:
        log_static_calibration(log, calibration)
    params = {k: s[k] for k in ("file", "device", "variant", "filter", "fs_hz", "timing",
                                "effective_rate_hz", "accel_only", "validated",
                                "threshold_positive_ms2", "threshold_negative_ms2",
                                "peaks_positive", "peaks_negative", "calibration")}
    params["gyro_gate"] = "open (accel-only)" if leg.accel_only else "w > 0 at the checked samples"
    log.write_json(f"/movements/{label}/parameters", t0, params)
    for row in leg.rows():
        log.write_json(f"/movements/{label}/events", row["start_ns"], row)
    summary = {k: v for k, v in s.items() if k != "calibration"}
    log.write_json(f"/movements/{label}/summary", t0, summary)


def write_movements_mcap(path, legs, *, compression: str = "zstd") -> None:
    """``legs``: [(label, LegResult, StaticCalibration or None)] -> one MCAP file (atomic)."""
    from stillpoint.engine.mcap.log import McapLog
    log = McapLog(path, compression=compression, what="movements MCAP")
    try:
        for label, leg, cal in legs:
            log_leg(log, label, leg, cal)
            log.write_metadata(f"movements_{label}", {"file": leg.path, "device": leg.device_key})
    except BaseException:
        log.abort()
        raise
    log.close()


def write_static_mcap(path, cal, *, compression: str = "zstd") -> None:
    """A static calibration as a one-message MCAP (plus device metadata)."""
    from stillpoint.engine.mcap.log import McapLog
    log = McapLog(path, compression=compression, what="static calibration MCAP")
    try:
        log_static_calibration(log, cal)
        log.write_metadata("device", {"device_key": cal.device_key or "",
                                      "serial": cal.device_serial or "",
                                      "source": cal.source or ""})
    except BaseException:
        log.abort()
        raise
    log.close()
