"""Six-orientation static calibration (Oh, Loeb & Smith 2024): the estimate from six face windows.

Error model per sample: r = S u + o + n, S = diag(G) + M (spec static-calibration.md §2).
From the six windows (``sixface.find_faces``), per axis j with the other axes i, l:

* offset o_j = mean of axis j over the pooled samples of the four windows in which j is not the
  gravity axis (w_i+, w_i-, w_l+, w_l-), as the paper and the reference code do;
* gain G_k = (m_k+ - m_k-) / 2 with m the offset-removed mean of axis k over its own windows;
* misalignment, signed (reference default): mean of (r_j - o_j) over the two windows where the
  other axes point up (= (M_ji + M_jl) / 2); absolute (paper): mean of |r_j - o_j| over the four
  non-gravity windows; also the reference's absolute-over-"up"-windows as a diagnostic;
* noise_k = 2 x SD of axis k over its +1 g window (paper; population SD);
* diagnostics: the classical midpoint offset (m_k+ + m_k-)/2 and the raw window means;
* optionally the full 3x3 matrix: column k of S = (mean vector over w_k+ - over w_k-) / 2,
  o = mean of the six window mean vectors, correction a = S^-1 (r - o).

The correction is a_k = (r_k - o_k) / G_k (g). As an engine estimate (the GGIR form of the
autocalibration, (raw + offset) * scale) it is offset = -o, scale = 1/G, method ``static-6``;
the whole static result rides in ``extra["static"]`` (and so in the store and the MCAP).
A missing face is an error naming it; the reference's silent NaNs only with ``allow_nan``.
"""

from __future__ import annotations

import datetime as _dt
from dataclasses import asdict, dataclass, field
from typing import Optional

import numpy as np

from stillpoint.drivers.errors import StillpointError

from .estimate import CalibrationEstimate
from .sixface import FACE_WORDS, FACES, FaceSearch, find_faces

STATIC_METHOD = "static-6"
G_MS2 = 9.80665  # m/s^2 per g (the reference code's constant)


class StaticCalibrationError(StillpointError):
    """A six-orientation calibration could not be made from this recording."""


class MissingFaceError(StaticCalibrationError):
    def __init__(self, missing, where: str = "", detail: str = ""):
        self.missing = list(missing)
        names = ", ".join(f"{f} ({FACE_WORDS[f]})" for f in self.missing)
        pre = f"{where}: " if where else ""
        super().__init__(f"{pre}{len(self.missing)} of the six faces not found: {names}"
                         + (f"; {detail}" if detail else ""))


def _iso(ns):
    if ns is None:
        return None
    return _dt.datetime.fromtimestamp(ns / 1e9, tz=_dt.timezone.utc).isoformat(
        timespec="milliseconds").replace("+00:00", "Z")


@dataclass
class StaticCalibration:
    """A static six-face estimate with its provenance (all vectors per axis x, y, z, in g)."""

    offset_g: list
    gain: list
    misalignment_signed_g: list
    misalignment_abs_g: list
    noise_g: list
    mode: str
    status: str = "ok"  # "ok" | "incomplete" (reference NaNs, allow_nan only)
    faces: dict = field(default_factory=dict)  # face -> window bounds, band, length, quality
    attempts: list = field(default_factory=list)  # the search's fallback steps
    warnings: list = field(default_factory=list)
    diagnostics: dict = field(default_factory=dict)
    matrix: Optional[list] = None  # full-matrix option: S (3x3, rows = measured axes)
    matrix_offset_g: Optional[list] = None
    device_key: Optional[str] = None
    device_serial: Optional[str] = None
    calibration_time_ns: Optional[int] = None  # first sample of the recording
    fit_start_ns: Optional[int] = None
    fit_end_ns: Optional[int] = None
    source: Optional[str] = None
    rate_hz: Optional[float] = None

    # ------------------------------------------------------------------ use
    @property
    def full_matrix(self) -> bool:
        return self.matrix is not None

    def apply(self, accel_g: np.ndarray, *, full_matrix: Optional[bool] = None) -> np.ndarray:
        """Corrected acceleration in g: (r - o) / G, or S^-1 (r - o) with the full matrix."""
        a = np.asarray(accel_g, np.float64)
        use = self.full_matrix if full_matrix is None else full_matrix
        if use:
            if self.matrix is None:
                raise StaticCalibrationError("this static calibration has no full matrix")
            sinv = np.linalg.inv(np.asarray(self.matrix, np.float64))
            return (a - np.asarray(self.matrix_offset_g)) @ sinv.T
        return (a - np.asarray(self.offset_g)) / np.asarray(self.gain)

    def to_dict(self) -> dict:
        d = asdict(self)
        d["calibration_time"] = _iso(self.calibration_time_ns)
        d["kind"] = "static-calibration"
        return d

    @staticmethod
    def from_dict(d: dict) -> "StaticCalibration":
        if d.get("kind") not in (None, "static-calibration"):
            raise StaticCalibrationError(f"not a static calibration (kind {d.get('kind')!r})")
        known = StaticCalibration.__dataclass_fields__
        return StaticCalibration(**{k: v for k, v in d.items() if k in known})

    def to_estimate(self) -> CalibrationEstimate:
        """The engine's estimate form: offset = -o, scale = 1/G (method ``static-6``)."""
        o = np.asarray(self.offset_g, np.float64)
        g = np.asarray(self.gain, np.float64)
        status = "ok" if self.status == "ok" and np.all(np.isfinite(o)) and np.all(np.isfinite(g)) \
            else "incomplete"
        return CalibrationEstimate(
            offset=-o, scale=1.0 / g, status=status, method=STATIC_METHOD,
            reason=f"six-orientation static calibration ({self.mode} mode)"
                   + (", full matrix" if self.full_matrix else ""),
            windows=sum(1 for f in self.faces.values() if f.get("samples")),
            fit_start_ns=self.fit_start_ns, fit_end_ns=self.fit_end_ns,
            device_key=self.device_key, extra={"static": self.to_dict()})

    @staticmethod
    def from_estimate(est: CalibrationEstimate) -> "StaticCalibration":
        s = (est.extra or {}).get("static")
        if est.method != STATIC_METHOD or not isinstance(s, dict):
            raise StaticCalibrationError(
                f"estimate of method {est.method!r} is not a static six-orientation calibration")
        return StaticCalibration.from_dict(s)


# ----------------------------------------------------------------------------- maths
def _pool(*idx) -> np.ndarray:
    """The reference's pooled sample set: concatenated, sorted (duplicates kept)."""
    return np.sort(np.concatenate([np.asarray(i, np.int64) for i in idx]))


def _mean(x: np.ndarray) -> float:
    return float(np.mean(x)) if x.size else float("nan")


def estimate_from_windows(acc_g: np.ndarray, windows: dict, *, full_matrix: bool = False) -> dict:
    """The formulas of §2 on given windows (face -> indices); NaN where a face is empty."""
    acc = np.asarray(acc_g, np.float64)
    w = {f: np.asarray(windows.get(f, ()), np.int64) for f in FACES}
    axes = "xyz"
    offset, gain, mis_s, mis_abs, mis_abs_up, noise, mid, raw_up, raw_down = ([] for _ in range(9))
    with np.errstate(invalid="ignore", divide="ignore"):
        for j, a in enumerate(axes):
            others = [b for b in axes if b != a]
            png = _pool(w["+" + others[0]], w["+" + others[1]])
            nng = _pool(w["-" + others[0]], w["-" + others[1]])
            non_g = _pool(png, nng)
            offset.append(_mean(acc[non_g, j]))
        o = np.asarray(offset)
        for j, a in enumerate(axes):
            others = [b for b in axes if b != a]
            png = _pool(w["+" + others[0]], w["+" + others[1]])
            non_g = _pool(png, _pool(w["-" + others[0]], w["-" + others[1]]))
            r_up = acc[w["+" + a], j]
            r_dn = acc[w["-" + a], j]
            m_up, m_dn = _mean(r_up - o[j]), _mean(r_dn - o[j])
            gain.append((m_up - m_dn) / 2.0)
            mis_s.append(_mean(acc[png, j] - o[j]))
            mis_abs_up.append(_mean(np.abs(acc[png, j] - o[j])))
            mis_abs.append(_mean(np.abs(acc[non_g, j] - o[j])))
            noise.append(2.0 * float(np.std(r_up)) if r_up.size else float("nan"))
            raw_up.append(_mean(r_up))
            raw_down.append(_mean(r_dn))
            mid.append((raw_up[-1] + raw_down[-1]) / 2.0)
    out = {"offset_g": offset, "gain": gain, "misalignment_signed_g": mis_s,
           "misalignment_abs_g": mis_abs, "noise_g": noise,
           "diagnostics": {"midpoint_offset_g": mid, "misalignment_abs_up_g": mis_abs_up,
                           "raw_mean_up_g": raw_up, "raw_mean_down_g": raw_down}}
    if full_matrix:
        means = {f: acc[w[f]].mean(axis=0) for f in FACES}
        s = np.stack([(means["+" + a] - means["-" + a]) / 2.0 for a in axes], axis=1)
        out["matrix"] = s.tolist()
        out["matrix_offset_g"] = np.mean(np.stack([means[f] for f in FACES]), axis=0).tolist()
    return out


def static_calibration(acc_g: np.ndarray, fs: float, *, mode: str = "reference",
                       full_matrix: bool = False, allow_nan: bool = False,
                       time_ns: Optional[np.ndarray] = None, window_s=None,
                       sd_cut: Optional[float] = None, units: str = "g",
                       range_g: Optional[float] = None, where: str = "",
                       device_key: Optional[str] = None,
                       device_serial: Optional[str] = None) -> StaticCalibration:
    """Search the six faces and estimate offset, gain, misalignment and noise (module docstring).

    ``units``: "g" or "m/s2" (converted to g first: the bands are in g). ``range_g``: the
    accelerometer range; a window touching it (clipping) is an error. ``allow_nan`` (reference
    mode only) reproduces the reference code's NaNs for a missing face instead of raising.
    ``time_ns``: per-sample times (window bounds are then reported as times too).
    """
    acc = np.asarray(acc_g, np.float64)
    if acc.ndim != 2 or acc.shape[1] != 3:
        raise StaticCalibrationError(f"{where or 'input'}: expected an (n, 3) array, got {acc.shape}")
    if units in ("m/s2", "m/s^2", "ms2"):
        acc = acc / G_MS2
    elif units != "g":
        raise ValueError(f"units must be 'g' or 'm/s2', not {units!r}")
    if acc.shape[0] == 0:
        raise StaticCalibrationError(f"{where or 'input'}: the recording has no samples")
    med = float(np.median(np.linalg.norm(acc, axis=1)))
    if med > 4.0:
        raise StaticCalibrationError(
            f"{where or 'input'}: median |a| is {med:.2f}: the data look like m/s^2, not g "
            "(pass units='m/s2')")
    if allow_nan and mode != "reference":
        raise ValueError("allow_nan reproduces the reference code: only in reference mode")
    search: FaceSearch = find_faces(acc, fs, mode, window_s=window_s, sd_cut=sd_cut)
    missing = search.missing
    if missing and not allow_nan:
        raise MissingFaceError(missing, where, _missing_hint(acc, fs))
    if range_g:
        lim = 0.999 * float(range_g)
        for f, idx in search.windows.items():
            if len(idx) and np.any(np.abs(acc[idx]) >= lim):
                raise StaticCalibrationError(
                    f"{where or 'input'}: clipping at the ±{range_g:g} g range inside the {f} "
                    f"({FACE_WORDS[f]}) window: the readings are not usable for calibration")
    est = estimate_from_windows(acc, search.windows, full_matrix=full_matrix and not missing)
    faces = {}
    t = None if time_ns is None else np.asarray(time_ns, np.int64)
    for f in FACES:
        idx = search.windows[f]
        d = dict(search.info.get(f, {}))
        if len(idx):
            a, b = int(idx[0]), int(idx[-1])
            d.update(start_index=a, end_index=b)
            if t is not None:
                d.update(start_ns=int(t[a]), end_ns=int(t[b]), start_time=_iso(int(t[a])),
                         end_time=_iso(int(t[b])))
            if t is not None and len(t):
                d.update(start_s=(int(t[a]) - int(t[0])) / 1e9, end_s=(int(t[b]) - int(t[0])) / 1e9)
            else:
                d.update(start_s=a / fs, end_s=b / fs)
        else:
            d.update(samples=0, missing=True)
        faces[f] = d
    if not missing:  # per-face quality after the correction (all modes)
        o, g = np.asarray(est["offset_g"]), np.asarray(est["gain"])
        for f in FACES:
            m = (acc[search.windows[f]].mean(axis=0) - o) / g
            k = "xyz".index(f[1])
            sign = 1.0 if f[0] == "+" else -1.0
            faces[f]["corrected_norm_error_g"] = float(abs(np.linalg.norm(m) - 1.0))
            faces[f]["corrected_tilt_deg"] = float(np.degrees(np.arccos(
                np.clip(sign * m[k] / np.linalg.norm(m), -1.0, 1.0))))
    status = "ok" if not missing else "incomplete"
    warnings = list(search.warnings)
    if missing:
        warnings.append("reference behaviour: NaN gain for the axes of the missing faces; offsets "
                        "of the other axes come from fewer than four orientations")
    return StaticCalibration(
        offset_g=est["offset_g"], gain=est["gain"],
        misalignment_signed_g=est["misalignment_signed_g"],
        misalignment_abs_g=est["misalignment_abs_g"], noise_g=est["noise_g"], mode=mode,
        status=status, faces=faces, attempts=search.attempts, warnings=warnings,
        diagnostics=est["diagnostics"], matrix=est.get("matrix"),
        matrix_offset_g=est.get("matrix_offset_g"), device_key=device_key,
        device_serial=device_serial,
        calibration_time_ns=None if t is None or not len(t) else int(t[0]),
        fit_start_ns=None if t is None or not len(t) else int(t[0]),
        fit_end_ns=None if t is None or not len(t) else int(t[-1]), rate_hz=float(fs))


def _missing_hint(acc: np.ndarray, fs: float) -> str:
    """Why faces may be missing: no still stretch at all, or holds that are too short."""
    n = acc.shape[0]
    if n < fs:
        return f"the recording holds only {n / fs:.2f} s of data"
    return ("each face needs a still hold of at least 1 s with that axis reading about ±1 g "
            "(10 s per face is the protocol)")


def read_calibration_recording(path):
    """A (short) calibration recording in memory: (time_ns, accel g (n, 3), DeviceInfo)."""
    from stillpoint.drivers import open_recording
    src = open_recording(path)
    info = src.info
    ts, acc = [], []
    try:
        for block in src:
            if block.n:
                ts.append(block.time_ns.copy())
                acc.append(block.accel_g())
    finally:
        src.close()
    if not ts:
        return np.zeros(0, np.int64), np.zeros((0, 3)), info
    return np.concatenate(ts), np.concatenate(acc), info


def static_calibration_file(path, *, mode: str = "reference", full_matrix: bool = False,
                            allow_nan: bool = False, window_s=None,
                            sd_cut: Optional[float] = None) -> StaticCalibration:
    """Static calibration of a six-orientation recording (.cwa/.bin): the device serial and
    range come from its header, the window bounds are reported as times."""
    time_ns, acc, info = read_calibration_recording(path)
    fs = float(info.sample_rate_nominal or 0)
    if fs <= 0:
        raise StaticCalibrationError(f"{path}: the header gives no sample rate")
    if acc.shape[0] == 0:
        raise StaticCalibrationError(f"{path}: the recording holds no samples")
    cal = static_calibration(acc, fs, mode=mode, full_matrix=full_matrix, allow_nan=allow_nan,
                             time_ns=time_ns, window_s=window_s, sd_cut=sd_cut,
                             range_g=info.accel_range_g, where=str(path),
                             device_key=info.device_key, device_serial=str(info.device_id))
    cal.source = str(path)
    return cal


def load_static_calibration(path) -> StaticCalibration:
    """A static calibration from JSON: the output of ``static-calibrate -o``/``--json``, a
    ``static-6`` engine estimate, or a store record holding one."""
    import json
    try:
        with open(path, encoding="utf-8") as f:
            d = json.load(f)
    except FileNotFoundError:
        raise StaticCalibrationError(f"{path}: no such calibration file") from None
    except (OSError, ValueError) as e:
        raise StaticCalibrationError(f"{path}: not a readable calibration JSON ({e})") from None
    if isinstance(d, dict) and "calibration" in d and isinstance(d["calibration"], dict):
        d = d["calibration"]
    if isinstance(d, dict) and "estimate" in d and isinstance(d["estimate"], dict):
        d = d["estimate"]
    if not isinstance(d, dict):
        raise StaticCalibrationError(f"{path}: not a calibration JSON object")
    try:
        if d.get("method") == STATIC_METHOD:
            return StaticCalibration.from_estimate(CalibrationEstimate.from_dict(d))
        if "offset_g" in d and "gain" in d:
            return StaticCalibration.from_dict(d)
    except (TypeError, ValueError) as e:
        raise StaticCalibrationError(f"{path}: malformed static calibration ({e})") from None
    raise StaticCalibrationError(f"{path}: not a six-orientation static calibration "
                                 f"(method {d.get('method')!r})")


def with_static_calibration(settings: dict, store_root, device_key: str) -> dict:
    """Run settings (a ``RunSettings`` override dict) with the store's latest static calibration
    of ``device_key`` applied instead of the autocalibration; unchanged when the store has none
    (the autocalibration then runs, as without a static calibration). ``store_root``: the store
    folder ("" or None: the default location)."""
    from .store import CalibrationStore
    est = CalibrationStore(store_root or None).latest_static(device_key)
    if est is None:
        return dict(settings)
    return dict(settings, static_calibration=est.to_dict())
