"""The sensor model: named effects, their parameters (with units in the keys), the JSON model file,
and the pure function that applies the deterministic part of the model to true acceleration.

A model is ``SensorModel(effects={name: {param: value}})``. Only effects present (and not
``"enabled": false``) are on. Effect names are stable identifiers; the discrepancy workflow fits
the same terms and writes the same JSON, which the simulator accepts as-is.

JSON model file::

    {
      "format": "stillpoint.sensor_model",
      "version": 1,
      "effects": {
        "offset":             {"x_mg": 12.0, "y_mg": -8.0, "z_mg": 45.0},
        "gain":               {"x_pct": 0.4, "y_pct": -0.6, "z_pct": 1.1},
        "temperature_offset": {"x_mg_per_c": 0.3, "y_mg_per_c": -0.2, "z_mg_per_c": 1.5,
                               "reference_c": 25.0},
        "noise":              {"x_ug_per_rthz": 400, "y_ug_per_rthz": 400, "z_ug_per_rthz": 550}
      }
    }

Per effect, an optional ``"enabled": false`` switches it off, and optional ``"uncertainty"``
(a dict of the same keys, 1-SD) and ``"note"`` (text) are carried along and ignored by the
simulator. Missing parameters are filled in by ``resolve_model`` from documented typical
distributions (the draws are recorded in the truth JSON, so a resolved model is complete).

Order of application (``EFFECT_ORDER``), each step acting on the output of the previous one,
with f the true specific force in the device frame (g), T_a the accelerometer's temperature
(the temperature sensor's reading T, or T passed through ``thermal_lag``) and t the time since the
start of the recording (s):

 1. misalignment         a = M f, M = I + cross-axis terms (x_from_y_pct: % of true y read on x)
 2. gain                 a_k *= 1 + gain_k/100
 3. temperature_gain     a_k *= 1 + tg_k/100 * (T_a - reference_c)
 4. offset               a_k += offset_k
 5. temperature_offset   a_k += to_k * (T_a - reference_c)
 6. nonlinearity         a_k += nl_k * a_k^2 (mg per g^2, on the value reaching this step)
 7. offset_drift         a_k += drift_k * t / 86400
 8. thermal_lag          (not a term of its own: T_a = first-order lag of T with tau_s; steps 3, 5)
 9. bias_instability     a_k += b_k(t), Gauss-Markov (OU) process, SD sigma, correlation time tau_s
10. noise                a_k += white noise, density in ug/sqrt(Hz), bandwidth = rate/2
11. clipping             at the device's range
12. quantisation         to the device's resolution (AX3 packed 1/256 g with the range's dropped
                         bits, AX3 unpacked 1/256 g, AX6 16-bit, GENEActiv 12-bit with its gain/offset)

Steps 1-8 are deterministic: ``apply_deterministic`` (a pure function). Timing effects act on
sample times, not values: ``rate_error``, ``clock``, ``halts``, ``restarts``; ``corrupt_sectors``
acts on the written file.
"""

from __future__ import annotations

import copy
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

import numpy as np

from stillpoint.engine.core.errors import StillpointError

MODEL_FORMAT = "stillpoint.sensor_model"
MODEL_VERSION = 1
AXES = ("x", "y", "z")


class ModelError(StillpointError, ValueError):
    """A sensor model (JSON file or --effect option) is invalid; the message says what and where."""


@dataclass(frozen=True)
class Param:
    key: str  # JSON key, units in the name
    unit: str  # canonical unit (for the CLI parser and docs)
    doc: str


def _axes(stem: str, unit_key: str, unit: str, doc: str) -> tuple[Param, ...]:
    return tuple(Param(f"{a}_{unit_key}", unit, f"{doc} on {a}") for a in AXES)


# Every effect: parameters (with units) and a one-line description with typical magnitudes.
EFFECTS: dict[str, dict] = {
    "misalignment": dict(
        params=tuple(Param(f"{a}_from_{b}_pct", "%", f"share of true {b} read on {a}")
                     for a in AXES for b in AXES if a != b),
        doc="cross-axis sensitivity / non-orthogonality (3x3); ADXL345 datasheet: cross-axis "
            "sensitivity +-1 %; package/PCB misalignment ~0.5-1 deg (~1-2 %)",
        deterministic=True),
    "gain": dict(
        params=_axes("gain", "pct", "%", "gain (sensitivity) error"),
        doc="gain error in %; van Hees 2014: scale factors within ~+-2 % (typ. <1 %)",
        deterministic=True),
    "temperature_gain": dict(
        params=_axes("tg", "pct_per_c", "%/C", "temperature coefficient of gain")
        + (Param("reference_c", "C", "reference temperature"),),
        doc="gain change per degC; ADXL345 datasheet: sensitivity change +-0.01-0.02 %/degC",
        deterministic=True),
    "offset": dict(
        params=_axes("offset", "mg", "mg", "zero-g offset"),
        doc="zero-g offset in mg; van Hees 2014 / ADXL345: tens of mg on x/y, up to ~100 mg on z",
        deterministic=True),
    "temperature_offset": dict(
        params=_axes("to", "mg_per_c", "mg/C", "zero-g offset temperature coefficient")
        + (Param("reference_c", "C", "reference temperature"),),
        doc="offset change per degC; van Hees 2014 Table 2: up to ~4 mg/degC, typ. <1 mg/degC",
        deterministic=True),
    "nonlinearity": dict(
        params=_axes("nl", "mg_per_g2", "mg/g^2", "quadratic nonlinearity"),
        doc="quadratic nonlinearity a += k a^2; ADXL345: nonlinearity ~0.5 % of full scale",
        deterministic=True),
    "offset_drift": dict(
        params=_axes("drift", "mg_per_day", "mg/day", "slow linear offset drift"),
        doc="slow offset drift over the recording, mg/day; MEMS ageing/long-term: <~1 mg/day",
        deterministic=True),
    "thermal_lag": dict(
        params=(Param("tau_s", "s", "time constant of the accelerometer die vs the temperature sensor"),),
        doc="the accelerometer sees the temperature through a first-order lag (tau ~5-20 min)",
        deterministic=True),
    "bias_instability": dict(
        params=_axes("sigma", "mg", "mg", "SD of the slowly wandering bias")
        + (Param("tau_s", "s", "correlation time"),),
        doc="Gauss-Markov (OU) bias wander; MEMS bias instability ~0.1-1 mg",
        deterministic=False),
    "noise": dict(
        params=_axes("noise", "ug_per_rthz", "ug/rtHz", "white noise density"),
        doc="white noise density; ADXL345 ~0.75-1.1 LSB rms (x/y) and ~1.1-1.5 LSB (z) at 100 Hz "
            "(3.9 mg/LSB), i.e. ~300-600 ug/sqrt(Hz); BMI160 (AX6) ~180 ug/sqrt(Hz)",
        deterministic=False),
    "clipping": dict(params=(), doc="values beyond the configured range saturate", deterministic=False),
    "quantisation": dict(
        params=(Param("mode", "", "'nearest' or 'floor' (firmware dropping low bits by an "
                                   "arithmetic shift)"),),
        doc="quantisation to the device resolution (always applied when writing a file)",
        deterministic=False),
    "rate_error": dict(
        params=(Param("pct", "%", "true sample rate minus nominal, % of nominal"),),
        doc="sample-rate error of the accelerometer's own oscillator; the AX3 GGIRread test file "
            "runs at 98.86 Hz for a nominal 100 Hz (-1.1 %), the AX6 one at 99.04 Hz",
        deterministic=False),
    "clock": dict(
        params=(Param("offset_s", "s", "device clock minus true time at the start"),
                Param("skew_ppm", "ppm", "clock rate error at the turnover temperature"),
                Param("curvature_ppm_per_c2", "ppm/C^2", "crystal temperature parabola"),
                Param("turnover_c", "C", "crystal turnover temperature")),
        doc="RTC: offset, skew (AX datasheet +-20-50 ppm) and the 32 kHz tuning-fork crystal "
            "parabola -0.035 ppm/degC^2 around 25 degC",
        deterministic=False),
    "halts": dict(
        params=(Param("events", "", "list of {start_s, duration_s}: sampling stops while time runs on"),
                Param("count", "", "number of random halts when events are not given"),
                Param("min_duration_s", "s", "shortest random halt"),
                Param("max_duration_s", "s", "longest random halt")),
        doc="sampling halts (Brønd et al. 2021: an AX3 halted after ~24 h; 2-400 s in the alignment tests)",
        deterministic=False),
    "restarts": dict(
        params=(Param("events", "", "list of {start_s, gap_s}: logging stops and restarts"),
                Param("count", "", "number of random restarts when events are not given"),
                Param("max_gap_s", "s", "longest random gap")),
        doc="logging restarts (sequence id back to 0, RESUME event; the Oxford sample file has one, "
            "4 min 4 s gap)",
        deterministic=False),
    "corrupt_sectors": dict(
        params=(Param("indices", "", "data sector/page indices to corrupt"),
                Param("count", "", "number of random sectors/pages to corrupt")),
        doc="corrupt sectors (.cwa checksum failure) or pages (.bin damaged hex)",
        deterministic=False),
}

ALIASES = {"temperature": "temperature_offset", "quantization": "quantisation",
           "drift": "offset_drift", "cross_axis": "misalignment"}

EFFECT_ORDER = ("misalignment", "gain", "temperature_gain", "offset", "temperature_offset",
                "nonlinearity", "offset_drift", "thermal_lag", "bias_instability", "noise",
                "clipping", "quantisation", "rate_error", "clock", "halts", "restarts",
                "corrupt_sectors")
DETERMINISTIC = tuple(n for n in EFFECT_ORDER if EFFECTS[n]["deterministic"])
META_KEYS = ("enabled", "uncertainty", "note")
DEFAULT_REFERENCE_C = 25.0

# A realistic default device (what `stillpoint simulate` uses without --effects).
DEFAULT_EFFECTS = ("offset", "gain", "temperature_offset", "bias_instability", "noise",
                   "clipping", "quantisation", "rate_error", "clock")


def canonical_name(name: str) -> str:
    n = name.strip().lower().replace("-", "_")
    n = ALIASES.get(n, n)
    if n not in EFFECTS:
        raise ModelError(f"unknown effect {name!r}; known effects: {', '.join(EFFECT_ORDER)} "
                         f"(aliases: {', '.join(sorted(ALIASES))})")
    return n


@dataclass
class SensorModel:
    """Effects that are on, each with its parameters (units in the keys; see EFFECTS)."""

    effects: dict[str, dict] = field(default_factory=dict)
    meta: dict = field(default_factory=dict)  # extra top-level keys, carried along

    def __post_init__(self):
        clean = {}
        for name, params in (self.effects or {}).items():
            n = canonical_name(name)
            if params is None:
                params = {}
            if not isinstance(params, dict):
                raise ModelError(f"effect {n!r}: parameters must be an object, got {params!r}")
            params = dict(params)
            if params.get("enabled", True) is False:
                continue
            params.pop("enabled", None)
            specs = {p.key: p for p in EFFECTS[n]["params"]}
            for k, v in params.items():
                if k not in specs and k not in META_KEYS:
                    raise ModelError(f"effect {n!r} has no parameter {k!r}; parameters: "
                                     f"{', '.join(sorted(specs)) or '(none)'}")
                if k in specs and k not in ("events", "indices", "mode", "count"):
                    if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
                        raise ModelError(f"effect {n!r}: {k} must be a finite number"
                                         f" (in {specs[k].unit or 'no unit'}), got {v!r}")
                elif k == "count" and (isinstance(v, bool) or not isinstance(v, int) or v < 0):
                    raise ModelError(f"effect {n!r}: count must be a non-negative integer, got {v!r}")
                elif k in ("events", "indices") and not isinstance(v, list):
                    raise ModelError(f"effect {n!r}: {k} must be a list, got {v!r}")
            clean[n] = params
        self.effects = {n: clean[n] for n in EFFECT_ORDER if n in clean}

    # -------------------------------------------------------------- queries
    def on(self, name: str) -> bool:
        return canonical_name(name) in self.effects

    def get(self, name: str, key: str, default=None):
        return self.effects.get(canonical_name(name), {}).get(key, default)

    def axis_vector(self, name: str, unit_key: str, default: float = 0.0) -> np.ndarray:
        """Per-axis parameter as a (3,) array (zeros when the effect is off)."""
        p = self.effects.get(canonical_name(name))
        if p is None:
            return np.zeros(3)
        return np.array([float(p.get(f"{a}_{unit_key}", default)) for a in AXES])

    def misalignment_matrix(self) -> np.ndarray:
        m = np.eye(3)
        p = self.effects.get("misalignment")
        if p:
            for i, a in enumerate(AXES):
                for j, b in enumerate(AXES):
                    if i != j:
                        m[i, j] = float(p.get(f"{a}_from_{b}_pct", 0.0)) / 100.0
        return m

    def with_effect(self, name: str, **params) -> "SensorModel":
        eff = copy.deepcopy(self.effects)
        n = canonical_name(name)
        eff.setdefault(n, {}).update(params)
        return SensorModel(eff, dict(self.meta))

    def without(self, *names: str) -> "SensorModel":
        drop = {canonical_name(n) for n in names}
        return SensorModel({k: v for k, v in copy.deepcopy(self.effects).items() if k not in drop},
                           dict(self.meta))

    # -------------------------------------------------------------- JSON
    def to_dict(self) -> dict:
        d = {"format": MODEL_FORMAT, "version": MODEL_VERSION}
        d.update({k: v for k, v in self.meta.items() if k not in ("format", "version", "effects")})
        d["effects"] = _jsonable(copy.deepcopy(self.effects))
        return d

    def to_json(self, indent: int = 2) -> str:
        return json.dumps(self.to_dict(), indent=indent)

    @staticmethod
    def from_dict(d: dict, *, source: str = "model") -> "SensorModel":
        if not isinstance(d, dict) or "effects" not in d or not isinstance(d["effects"], dict):
            raise ModelError(f"{source}: a sensor model is a JSON object with an 'effects' object")
        fmt = d.get("format", MODEL_FORMAT)
        if fmt != MODEL_FORMAT:
            raise ModelError(f"{source}: format is {fmt!r}, expected {MODEL_FORMAT!r}")
        if int(d.get("version", MODEL_VERSION)) > MODEL_VERSION:
            raise ModelError(f"{source}: model version {d['version']} is newer than this simulator "
                             f"({MODEL_VERSION})")
        meta = {k: v for k, v in d.items() if k not in ("format", "version", "effects")}
        try:
            return SensorModel(d["effects"], meta)
        except ModelError as e:
            raise ModelError(f"{source}: {e}") from None


def _jsonable(x):
    if isinstance(x, dict):
        return {k: _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return _jsonable(x.tolist())
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, np.floating):
        return float(x)
    return x


def load_model(path) -> SensorModel:
    """Read a model JSON file (a truth JSON is accepted too: its 'sensor_model' is used)."""
    p = Path(path)
    try:
        d = json.loads(p.read_text())
    except FileNotFoundError:
        raise ModelError(f"{p}: no such model file") from None
    except (OSError, json.JSONDecodeError) as e:
        raise ModelError(f"{p}: not a readable JSON model ({e})") from None
    if isinstance(d, dict) and "effects" not in d and isinstance(d.get("sensor_model"), dict):
        d = d["sensor_model"]
    return SensorModel.from_dict(d, source=str(p))


def save_model(model: SensorModel, path) -> None:
    from stillpoint.engine.core.outputs import atomic_output
    with atomic_output(path, binary=False, what="model") as f:
        f.write(model.to_json() + "\n")


# ----------------------------------------------------------------------------- the pure function
def first_order_lag(temperature_c, time_s, tau_s: float, initial: Optional[float] = None) -> np.ndarray:
    """Temperature seen through a first-order lag (exact for piecewise-linear input).

    ``temperature_c`` and ``time_s`` are (n,) in time order (irregular spacing allowed, e.g. the
    still windows of a recording). Starts at ``initial`` (default: the first value).
    """
    T = np.asarray(temperature_c, np.float64).reshape(-1)
    t = np.asarray(time_s, np.float64).reshape(-1)
    if T.size == 0:
        return T.copy()
    if tau_s <= 0:
        return T.copy()
    dt = np.diff(t)
    if np.any(dt < 0):
        raise ValueError("first_order_lag needs times in increasing order")
    a = np.exp(-dt / tau_s)
    # exact response to a linear ramp between the two samples (first-order hold)
    with np.errstate(invalid="ignore", divide="ignore"):
        b = np.where(dt > 0, 1.0 - tau_s / np.where(dt > 0, dt, 1.0) * (1.0 - a), 0.0)
    u = (1.0 - a - b) * T[:-1] + b * T[1:]
    y0 = T[0] if initial is None else float(initial)
    # y[i+1] = a_i y[i] + u_i: a time-varying linear recursion, solved in closed form in blocks
    out = np.empty_like(T)
    out[0] = y0
    _linear_recursion(a, u, y0, out[1:])
    return out


def _linear_recursion(a: np.ndarray, u: np.ndarray, y0: float, out: np.ndarray, block: int = 256) -> None:
    """out[i] = a[i] * out[i-1] + u[i] (out[-1] = y0), vectorised per block via cumulative products."""
    y = y0
    n = a.shape[0]
    for s in range(0, n, block):
        aa = a[s:s + block]
        uu = u[s:s + block]
        # cumulative products stay well-conditioned inside a block (a in (0, 1])
        P = np.cumprod(aa)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            if np.all(P > 1e-200):
                out[s:s + block] = P * (y + np.cumsum(uu / P))
            else:  # extremely fast decay inside the block: fall back to the plain recursion
                for i in range(aa.shape[0]):
                    y = aa[i] * y + uu[i]
                    out[s + i] = y
                continue
        y = out[s + aa.shape[0] - 1]


def accelerometer_temperature(model: SensorModel, temperature_c, time_s,
                              initial: Optional[float] = None) -> np.ndarray:
    """T_a: the temperature the accelerometer sees (lagged if ``thermal_lag`` is on)."""
    T = np.asarray(temperature_c, np.float64)
    if not model.on("thermal_lag"):
        return T
    return first_order_lag(T, time_s, float(model.get("thermal_lag", "tau_s", 600.0)), initial)


_TILES: dict = {}


def axis_tile(v: np.ndarray, n: int) -> np.ndarray:
    """(3 n,) the per-axis values v (3,) repeated n times: a per-axis operation on a C-contiguous
    (n, 3) array becomes one contiguous loop over its flat view (the (n, 3)-by-(3,) broadcast
    and the strided column loops are several times slower); element for element the same
    operation, so the same numbers. Cached per value (read-only)."""
    key = (v.dtype.str, v.tobytes())
    t = _TILES.get(key)
    if t is None or t.shape[0] < 3 * n:
        if len(_TILES) > 16:
            _TILES.clear()
        t = np.tile(v, n)
        t.flags.writeable = False
        _TILES[key] = t
    return t[:3 * n]


def per_axis(op, a: np.ndarray, v: np.ndarray) -> None:
    """``op(a[:, j], v[j], out=a[:, j])`` for the three axes of a (n, 3) array, in place."""
    if a.flags.c_contiguous:
        flat = a.reshape(-1)
        op(flat, axis_tile(v, a.shape[0]), out=flat)
    else:
        for j in range(3):
            c = a[:, j]
            op(c, v[j], out=c)


def _minus(T: np.ndarray, ref: float, dt) -> np.ndarray:
    """``(T.astype(float64) - ref).astype(dt)`` in one pass (computed in float64, rounded once
    to dt: the same numbers)."""
    out = np.empty(T.shape, dt)
    np.subtract(T, ref, out=out, dtype=np.float64, casting="unsafe")
    return out


def apply_deterministic(accel_g, model: SensorModel, *, temperature_c=None, time_s=None,
                        accel_temperature_c=None) -> np.ndarray:
    """What the sensor reads (g, before noise/clipping/quantisation) for true specific force.

    accel_g: (n, 3) true specific force in the device frame, g, float64 (float32 is kept as
    float32) (e.g. the 1 g gravity vector of a
    still window). temperature_c: (n,) temperature-sensor reading, degC (needed when a
    temperature effect is on). time_s: (n,) seconds since the start of the recording (needed for
    offset_drift, and for thermal_lag when ``accel_temperature_c`` is not given; then the rows must
    be a time-ordered series). accel_temperature_c: (n,) the accelerometer's own temperature, if
    already known (e.g. carried across chunks); overrides the thermal_lag computation.

    Steps 1-8 of the module docstring, in that order. Pure: no randomness, no state.
    """
    f = np.asarray(accel_g)
    if f.dtype not in (np.float32, np.float64):
        f = f.astype(np.float64)
    if f.ndim != 2 or f.shape[1] != 3:
        raise ValueError(f"accel_g must be (n, 3), got {f.shape}")
    dt = f.dtype  # float32 input stays float32 (the simulator's fast path)
    eff = model.effects
    a = f @ model.misalignment_matrix().T.astype(dt) if "misalignment" in eff else f.copy()
    needs_T = any(k in eff for k in ("temperature_gain", "temperature_offset"))
    Ta = None
    if needs_T:
        if accel_temperature_c is not None:
            Ta = np.asarray(accel_temperature_c).reshape(-1)  # float64 where used (_minus)
        else:
            if temperature_c is None:
                raise ValueError("a temperature effect is on: temperature_c is required")
            if "thermal_lag" in eff:
                if time_s is None:
                    raise ValueError("thermal_lag is on: time_s is required")
                Ta = accelerometer_temperature(model, temperature_c, time_s)
            else:
                Ta = np.asarray(temperature_c, np.float64).reshape(-1)
        if Ta.shape[0] != a.shape[0]:
            raise ValueError("temperature must have one value per row of accel_g")
    # (n, 3)-by-(3,) steps column by column (numpy's broadcast loop over 3 is several times
    # slower); each column gets the same operations as in the broadcast form, so the same numbers
    cols = [a[:, j] for j in range(3)]
    if "gain" in eff:
        v = (1.0 + model.axis_vector("gain", "pct") / 100.0).astype(dt)
        per_axis(np.multiply, a, v)  # c *= v[j] for each column c
    if "temperature_gain" in eff:
        ref = float(eff["temperature_gain"].get("reference_c", DEFAULT_REFERENCE_C))
        v = (model.axis_vector("temperature_gain", "pct_per_c") / 100.0).astype(dt)
        dT = _minus(Ta, ref, dt)
        for j, c in enumerate(cols):
            c *= 1.0 + dT * v[j]
    if "offset" in eff:
        v = (model.axis_vector("offset", "mg") / 1000.0).astype(dt)
        per_axis(np.add, a, v)  # c += v[j] for each column c
    if "temperature_offset" in eff:
        ref = float(eff["temperature_offset"].get("reference_c", DEFAULT_REFERENCE_C))
        v = (model.axis_vector("temperature_offset", "mg_per_c") / 1000.0).astype(dt)
        dT = _minus(Ta, ref, dt)
        for j, c in enumerate(cols):
            c += dT * v[j]
    if "nonlinearity" in eff:
        v = (model.axis_vector("nonlinearity", "mg_per_g2") / 1000.0).astype(dt)
        for j, c in enumerate(cols):
            c += v[j] * (c * c)
    if "offset_drift" in eff:
        if time_s is None:
            raise ValueError("offset_drift is on: time_s is required")
        t = np.asarray(time_s, np.float64).reshape(-1)
        v = (model.axis_vector("offset_drift", "mg_per_day") / 1000.0).astype(dt)
        td = (t / 86400.0).astype(dt)
        for j, c in enumerate(cols):
            c += td * v[j]
    return a


def ggir_equivalent(model: SensorModel, temperature_ref: float) -> dict:
    """The GGIR-form correction (offset, scale, tempoffset) that exactly undoes offset, gain and
    temperature_offset: cal = (raw + offset) * scale + (T - temperature_ref) * tempoffset.

    Raises ModelError if another deterministic effect is on (not representable in GGIR form).
    """
    other = [n for n in DETERMINISTIC if n in model.effects
             and n not in ("offset", "gain", "temperature_offset")]
    if other:
        raise ModelError(f"not representable in the GGIR form: {', '.join(other)}")
    g = 1.0 + model.axis_vector("gain", "pct") / 100.0
    o = model.axis_vector("offset", "mg") / 1000.0
    to = model.axis_vector("temperature_offset", "mg_per_c") / 1000.0
    ref = float(model.get("temperature_offset", "reference_c", DEFAULT_REFERENCE_C))
    # raw = g f + o + to (T - ref)  =>  f = (raw - o - to (Tr - ref)) / g - to / g (T - Tr)
    return {"offset": (-(o + to * (temperature_ref - ref))).tolist(),
            "scale": (1.0 / g).tolist(),
            "tempoffset": (-to / g).tolist(),
            "temperature_ref": float(temperature_ref)}


# ----------------------------------------------------------------------------- typical values
# Noise density defaults per device (ug/sqrt(Hz)): AX3 = ADXL345 (see EFFECTS["noise"]), AX6 =
# Bosch BMI160 datasheet 180 ug/sqrt(Hz); GENEActiv: no published figure, its still-window SD in
# the public test files is similar to the AX3's, so the ADXL345 values are used.
DEFAULT_NOISE_UG = {"ax3": (400.0, 400.0, 550.0), "ax6": (180.0, 180.0, 180.0),
                    "geneactiv": (400.0, 400.0, 550.0)}


def _effect_rng(seed: int, name: str) -> np.random.Generator:
    import zlib
    return np.random.default_rng(np.random.SeedSequence([int(seed), 1, zlib.crc32(name.encode())]))


def resolve_model(model: SensorModel, *, seed: int, device: str = "ax3",
                  duration_s: float = 7 * 86400.0) -> SensorModel:
    """Fill every missing parameter of the effects that are on with a draw from its typical
    distribution (each effect from its own random stream, so switching one effect on or off does
    not change the others). Explicit values are kept. The result is complete and is what the
    truth JSON records."""
    eff = copy.deepcopy(model.effects)
    dev = device.lower()

    def fill(name, key, draw):
        p = eff[name]
        if key not in p:
            p[key] = float(draw())

    for name, p in eff.items():
        r = _effect_rng(seed, name)
        if name == "offset":  # tens of mg on x/y, up to ~0.1 g on z
            for a, sd in zip(AXES, (25.0, 25.0, 45.0)):
                fill(name, f"{a}_mg", lambda sd=sd: np.clip(r.normal(0, sd), -100, 100))
        elif name == "gain":  # within +-2 %
            for a in AXES:
                fill(name, f"{a}_pct", lambda: np.clip(r.normal(0, 0.8), -2, 2))
        elif name == "temperature_offset":  # typically < 1 mg/degC, up to ~4
            for a, sd in zip(AXES, (0.4, 0.4, 0.8)):
                fill(name, f"{a}_mg_per_c", lambda sd=sd: np.clip(r.normal(0, sd), -4, 4))
            p.setdefault("reference_c", DEFAULT_REFERENCE_C)
        elif name == "temperature_gain":
            for a in AXES:
                fill(name, f"{a}_pct_per_c", lambda: np.clip(r.normal(0, 0.01), -0.05, 0.05))
            p.setdefault("reference_c", DEFAULT_REFERENCE_C)
        elif name == "misalignment":
            for prm in EFFECTS[name]["params"]:
                fill(name, prm.key, lambda: np.clip(r.normal(0, 0.5), -2, 2))
        elif name == "nonlinearity":
            for a in AXES:
                fill(name, f"{a}_mg_per_g2", lambda: np.clip(r.normal(0, 2.0), -8, 8))
        elif name == "offset_drift":
            for a in AXES:
                fill(name, f"{a}_mg_per_day", lambda: np.clip(r.normal(0, 0.3), -1.5, 1.5))
        elif name == "thermal_lag":
            fill(name, "tau_s", lambda: r.uniform(300, 1200))
        elif name == "bias_instability":
            for a in AXES:
                p.setdefault(f"{a}_mg", 0.3)
            p.setdefault("tau_s", 3600.0)
        elif name == "noise":
            for a, v in zip(AXES, DEFAULT_NOISE_UG.get(dev, DEFAULT_NOISE_UG["ax3"])):
                p.setdefault(f"{a}_ug_per_rthz", v)
        elif name == "quantisation":
            p.setdefault("mode", "nearest")
            if p["mode"] not in ("nearest", "floor"):
                raise ModelError(f"quantisation mode must be 'nearest' or 'floor', got {p['mode']!r}")
        elif name == "rate_error":
            fill(name, "pct", lambda: np.clip(r.normal(0, 0.5), -1.5, 1.5))
        elif name == "clock":
            fill(name, "offset_s", lambda: r.uniform(-10, 10))
            fill(name, "skew_ppm", lambda: np.clip(r.normal(0, 20), -50, 50))
            p.setdefault("curvature_ppm_per_c2", -0.035)
            p.setdefault("turnover_c", 25.0)
        elif name == "halts":
            if "events" not in p:
                n = int(p.get("count", 1))
                lo, hi = float(p.get("min_duration_s", 2.0)), float(p.get("max_duration_s", 400.0))
                first = 86400.0 if duration_s > 2 * 86400.0 else 0.2 * duration_s
                starts = np.sort(r.uniform(first, 0.9 * duration_s, n))
                p["events"] = [{"start_s": float(s), "duration_s": float(r.uniform(lo, hi))}
                               for s in starts]
        elif name == "restarts":
            if "events" not in p:
                n = int(p.get("count", 1))
                starts = np.sort(r.uniform(0.1 * duration_s, 0.9 * duration_s, n))
                hi = float(p.get("max_gap_s", 300.0))
                p["events"] = [{"start_s": float(s), "gap_s": float(r.uniform(min(10.0, hi), hi))}
                               for s in starts]
        elif name == "corrupt_sectors":
            p.setdefault("count", 3)
        _check_events(name, p)
    return SensorModel(eff, dict(model.meta))


def _check_events(name: str, p: dict) -> None:
    if name not in ("halts", "restarts") or "events" not in p:
        return
    need = ("start_s", "duration_s") if name == "halts" else ("start_s", "gap_s")
    for ev in p["events"]:
        if not isinstance(ev, dict) or any(k not in ev for k in need):
            raise ModelError(f"{name}: every event needs {', '.join(need)}, got {ev!r}")
        if float(ev[need[1]]) < 0 or float(ev["start_s"]) < 0:
            raise ModelError(f"{name}: negative time in event {ev!r}")


# ----------------------------------------------------------------------------- CLI syntax
# --effect NAME[:KEY=VALUE[UNIT][,KEY=VALUE[UNIT]...]]
# KEY is a full parameter key (z_mg_per_c) or its short form: an axis letter (x, y, z) for the
# effect's per-axis parameter, or the parameter's stem (tau, sigma, pct, offset, skew, ...).
# KEY 'all' (or 'xyz') sets the three per-axis values at once.
# VALUE may carry a unit, converted to the key's unit: 3.9mg/C, 0.1g, 20ppm, 26h, 300s, 0.5%.
_UNIT_FACTORS = {
    "mg": {"mg": 1.0, "g": 1000.0, "ug": 1e-3},
    "mg/C": {"mg/c": 1.0, "g/c": 1000.0, "ug/c": 1e-3},
    "mg/g^2": {"mg/g^2": 1.0, "mg/g2": 1.0},
    "mg/day": {"mg/day": 1.0, "mg/d": 1.0, "ug/day": 1e-3, "ug/d": 1e-3, "mg/h": 24.0},
    "%": {"%": 1.0, "pct": 1.0, "ppm": 1e-4},
    "%/C": {"%/c": 1.0, "pct/c": 1.0, "ppm/c": 1e-4},
    "ppm": {"ppm": 1.0, "%": 1e4},
    "ppm/C^2": {"ppm/c^2": 1.0, "ppm/c2": 1.0},
    "C": {"c": 1.0},
    "s": {"s": 1.0, "ms": 1e-3, "min": 60.0, "h": 3600.0, "d": 86400.0},
    "ug/rtHz": {"ug/rthz": 1.0, "ug/sqrt(hz)": 1.0, "ug/√hz": 1.0, "mg/rthz": 1000.0},
}


def _convert(value: str, unit: str, effect: str, key: str) -> float:
    import re
    m = re.fullmatch(r"\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*(.*?)\s*", value)
    if not m:
        raise ModelError(f"--effect {effect}: {key}={value!r} is not a number")
    x, u = float(m.group(1)), m.group(2).lower().replace("°", "").replace("degc", "c").replace("deg", "")
    if not u:
        return x
    table = _UNIT_FACTORS.get(unit, {})
    if u not in table:
        raise ModelError(f"--effect {effect}: unit {m.group(2)!r} does not fit {key} (in {unit}); "
                         f"use one of {', '.join(sorted(table)) or 'no unit'}")
    return x * table[u]


def _whole(value: str, effect: str, key: str, limit: int = 10**7) -> int:
    """A count or index of an ``--effect`` option: a whole number in [0, limit]."""
    try:
        x = float(value)
    except ValueError:
        x = float("nan")
    if not (0 <= x <= limit and x == int(x)):
        raise ModelError(f"--effect {effect}: {key}={value.strip()!r} is not a whole number in "
                         f"[0, {limit}]")
    return int(x)


def _unit_key(name: str) -> str:
    """The per-axis key suffix of an effect (x_<suffix>), or '' if it has none."""
    for p in EFFECTS[name]["params"]:
        if p.key.startswith("x_") and "_from_" not in p.key:
            return p.key[2:]
    return ""


def parse_effect_option(text: str) -> tuple[str, dict]:
    """Parse one ``--effect`` value into (effect name, {json key: value})."""
    name, _, rest = text.partition(":")
    name = canonical_name(name)
    params: dict = {}
    if not rest.strip():
        return name, params
    specs = {p.key: p for p in EFFECTS[name]["params"]}
    event: dict = {}
    for item in rest.split(","):
        if not item.strip():
            continue
        k, eq, v = item.partition("=")
        k = k.strip().lower()
        if not eq:
            raise ModelError(f"--effect {name}: expected KEY=VALUE, got {item!r}")
        if name in ("halts", "restarts") and k in ("at", "start", "start_s", "duration", "duration_s",
                                                    "gap", "gap_s"):
            key = {"at": "start_s", "start": "start_s", "duration": "duration_s", "gap": "gap_s"}.get(k, k)
            event[key] = _convert(v, "s", name, key)
            continue
        if name == "corrupt_sectors" and k == "indices":
            params["indices"] = [_whole(s, name, k) for s in v.replace(";", " ").split()]
            continue
        if name == "quantisation" and k == "mode":
            params["mode"] = v.strip()
            continue
        if k in ("all", "xyz", "sigma") and f"x_{_unit_key(name)}" in specs:
            for a in AXES:
                key = f"{a}_{_unit_key(name)}"
                params[key] = _convert(v, specs[key].unit, name, key)
            continue
        key = k if k in specs else None
        if key is None:
            cands = [s for s in specs if s.startswith(k + "_") or s.split("_")[0] == k]
            if len(cands) == 1:
                key = cands[0]
            else:
                raise ModelError(f"--effect {name}: unknown parameter {k!r}; parameters: "
                                 f"{', '.join(specs) or '(none)'}")
        spec = specs[key]
        if spec.key == "count":
            params[key] = _whole(v, name, key)
        else:
            params[key] = _convert(v, spec.unit, name, key)
    if event:
        need = ("start_s", "duration_s") if name == "halts" else ("start_s", "gap_s")
        missing = [k for k in need if k not in event]
        if missing:
            raise ModelError(f"--effect {name}: an event needs at=..,{'duration' if name == 'halts' else 'gap'}=..")
        params["events"] = [event]
    return name, params


def effect_help() -> str:
    """Text for --help: every effect, its parameters and units."""
    lines = []
    for n in EFFECT_ORDER:
        e = EFFECTS[n]
        ps = ", ".join(f"{p.key}" + (f" [{p.unit}]" if p.unit else "") for p in e["params"])
        lines.append(f"  {n}: {e['doc']}" + (f"\n      params: {ps}" if ps else ""))
    return "\n".join(lines)
