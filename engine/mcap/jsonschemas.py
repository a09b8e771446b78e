"""JSON schemas (``jsonschema`` encoding, JSON Schema draft 2020-12) of the JSON topics:
``/calibration``, ``/qc``, the alignment topics and static-calibration estimates.

With a schema Foxglove's Raw Messages panel lists the fields and its Plot panel offers every
numeric one (e.g. ``/calibration.offset[0]``, ``/calibration.error_after_mg``) against time.
Every schema allows further properties, so a newer writer stays readable.
"""

from __future__ import annotations

import json
from dataclasses import dataclass


@dataclass(frozen=True)
class JsonSchema:
    name: str
    text: str  # the JSON Schema document

    @property
    def data(self) -> bytes:
        return self.text.encode()


def _schema(name: str, title: str, props: dict, required=()) -> JsonSchema:
    doc = {"$schema": "https://json-schema.org/draft/2020-12/schema", "title": title,
           "type": "object", "properties": props, "additionalProperties": True}
    if required:
        doc["required"] = list(required)
    return JsonSchema(name, json.dumps(doc, sort_keys=True, separators=(",", ":")))


def _num(desc: str) -> dict:
    return {"type": ["number", "null"], "description": desc}


def _int(desc: str) -> dict:
    return {"type": ["integer", "null"], "description": desc}


def _str(desc: str) -> dict:
    return {"type": ["string", "null"], "description": desc}


def _vec(desc: str) -> dict:
    return {"type": "array", "items": {"type": "number"}, "minItems": 3, "maxItems": 3,
            "description": desc}


_ESTIMATE_PROPS = {
    "offset": _vec("offset per axis, g (corrected = (raw + offset + tempoffset*(T-Tref)) * scale)"),
    "scale": _vec("scale per axis"),
    "tempoffset": _vec("offset per degC of temperature above temperature_ref, g/degC"),
    "temperature_ref": _num("reference temperature, degC"),
    "status": _str("fit outcome: ok, high_error, identity, reverted, no_nonmovement, ..."),
    "reason": _str("one line for humans"),
    "method": _str("autocal-c1, autocal-c2, static-6, identity, ..."),
    "error_before_mg": _num("mean |norm - 1| of the fit's windows before correction, mg"),
    "error_after_mg": _num("the same after correction, mg"),
    "windows": _int("windows used by the fit"),
    "iterations": _int("fit iterations"),
    "hours_used": _num("hours of data the fit used"),
    "fit_start_ns": _int("first sample of the data fitted on, ns since the Unix epoch (UTC)"),
    "fit_end_ns": _int("end of the data fitted on, ns since the Unix epoch (UTC)"),
    "fitted_at_ns": _int("when the estimate was fitted (data time, ns); for a prior, the end of "
                         "the data it was fitted on, which may precede this recording"),
    "effective_from_ns": _int("data time from which it is applied (null: from the start)"),
    "device_key": _str("device the estimate belongs to"),
    "applied": {"type": "boolean", "description": "whether the corrected stream uses it"},
    "prior": {"type": "boolean", "description": "the estimate in force before the first refit"},
    "uncertainty": {"type": ["object", "null"],
                    "description": "one standard error per coefficient, same units (null: not computed)",
                    "properties": {"offset": _vec("SE of offset, g"), "scale": _vec("SE of scale"),
                                   "tempoffset": _vec("SE of tempoffset, g/degC"),
                                   "temperature_ref": _num("SE of temperature_ref, degC")}},
    "extra": {"type": "object", "description": "fit diagnostics (warnings: extra.warnings)"},
}

CALIBRATION = _schema("stillpoint.CalibrationEstimate", "Calibration estimate", _ESTIMATE_PROPS,
                      required=("offset", "scale", "tempoffset", "status", "applied"))

STATIC_CALIBRATION = _schema("stillpoint.StaticCalibrationEstimate",
                             "Static (multi-position) calibration estimate",
                             dict(_ESTIMATE_PROPS,
                                  positions=_int("still positions used"),
                                  residual_mg=_num("RMS residual of the fit, mg")),
                             required=("offset", "scale", "status"))

QC = _schema("stillpoint.QcEvent", "Reader or engine event", {
    "source": _str("reader or engine"),
    "reason": _str("what happened (checksum, sequence_break, segment_start, calibration, ...)"),
    "index": _int("sector/page index (-1 when not tied to one)"),
    "detail": _str("one line for humans"),
    "time_ns": _int("data time of the event, ns since the Unix epoch (UTC)"),
    "samples": _int("samples affected"),
    "segment": _int("segment number"),
    "status": _str("calibration status (reason = calibration)"),
    "applied": {"type": "boolean"},
}, required=("source", "reason"))

ALIGNMENT_BLOCK_LAG = _schema("stillpoint.AlignmentBlockLag", "Lag of one block", {
    "index": _int("block number"),
    "start_s": _num("block start, s from the reference's first sample"),
    "centroid_s": _num("activity-weighted centre of the block, s"),
    "duration_s": _num("block length, s"),
    "valid": {"type": "boolean"},
    "coverage_ref": _num("fraction of the block with reference data"),
    "coverage_other": _num("fraction of the block with data of the other device"),
    "lag": _num("lag of the other device, samples"),
    "lag_s": _num("lag of the other device, s"),
    "corr": _num("peak correlation"),
    "activity_ref": _num("reference activity in the block"),
    "activity_other": _num("other device's activity in the block"),
    "reason": _str("why the block is not valid"),
})

ALIGNMENT_ESTIMATE = _schema("stillpoint.AlignmentEstimate", "Clock alignment estimate", {
    "final": {"type": "boolean", "description": "the run's final estimate"},
    "model": _str("clock model"),
    "block": _int("last block used (online estimates)"),
    "initial_offset_s": _num("offset of the other clock at the reference's start, s"),
    "drift_s_per_day": _num("drift of the other clock, s/day"),
    "drift_day7_s": _num("accumulated drift after 7 days, s"),
    "blocks_used": _int("blocks used by the fit"),
    "rmse_samples": _num("fit residual, samples"),
})

ALL_JSON = (CALIBRATION, STATIC_CALIBRATION, QC, ALIGNMENT_BLOCK_LAG, ALIGNMENT_ESTIMATE)

# the sleep topics (engine/sleep/tap.py): one message per night at its onset, one per sustained
# inactivity bout at its start; the night's fields are the nights table's (docs/sleep.md)
SLEEP_NIGHT = _schema("stillpoint.SleepNight", "Night (sleep period and its summary)", {
    "night": _str("the evening's local date, YYYY-MM-DD"),
    "guider": _str("what guided the sleep period: sleeplog, HDCZA, HDCZA+invalid, L512 or none"),
    "onset_local": _str("sleep onset, local ISO 8601 (device clock when the zone is unknown)"),
    "wake_local": _str("wake, local ISO 8601"),
    "onset_utc": _str("sleep onset, ISO 8601 UTC (empty when the zone is unknown)"),
    "wake_utc": _str("wake, ISO 8601 UTC"),
    "onset_ns": _int("sleep onset, ns (the log's time base)"),
    "wake_ns": _int("wake, ns"),
    "spt_hours": _num("sleep period time, h"),
    "sleep_hours": _num("sustained inactivity inside the sleep period, h"),
    "waso_hours": _num("wake after sleep onset, h"),
    "awakenings": _int("wake runs between inactivity bouts"),
    "efficiency": _num("sleep / sleep period"),
    "nonwear_spt_hours": _num("nonwear or gap inside the sleep period, h"),
    "window_hours": _num("the noon-to-noon window in the data, h"),
    "dst": _int("1 when the window is 23 or 25 h"),
    "daysleeper": _int("1 when the window came from the re-run 6 h later"),
    "hdcza_threshold_deg": _num("HDCZA angle threshold, degrees"),
    "fraction_night_invalid": _num("GGIR's fraction of the night without valid data"),
    "cleaningcode": _int("GGIR part 4 cleaning code"),
    "window_cut": _str("start, end or both: the recording starts or ends inside the window"),
    "night_valid": _int("1: the night counts in summaries"),
}, required=("night", "guider"))
SLEEP_BOUT = _schema("stillpoint.SleepInactivityBout", "Sustained inactivity bout", {
    "start_ns": _int("start, ns (the log's time base)"),
    "end_ns": _int("end, ns"),
    "duration_s": _num("duration, s"),
}, required=("start_ns", "end_ns"))
