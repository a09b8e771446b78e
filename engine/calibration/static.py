"""Six-orientation static calibration (Oh, Loeb & Smith 2024): the estimate from six face windows.

Error model per sample: r = S u + o + n, S = diag(G) + M (spec static-calibration.md §2).
From the six windows (``sixface.find_faces``), per axis j with the other axes i, l:

* offset o_j, reference and paper modes: mean of axis j over the pooled samples of the four
  windows in which j is not the gravity axis (w_i+, w_i-, w_l+, w_l-), as the paper and the
  reference code do. Robust mode: the face pair's midpoint (m_j+ + m_j-) / 2 of axis j's own
  +-1 g holds, which is what the six-face geometry defines: the pooled non-gravity mean cancels
  cross-axis coupling only when the +i and -i windows hold equally many samples (the robust
  search keeps each face's whole still hold, 7-12 s in practice), and carries any tilt of the
  placements at first order;
* gain G_k = (m_k+ - m_k-) / 2 with m the offset-removed mean of axis k over its own windows;
* cross-axis coupling (reported, all modes): M_jk = (r_j over w_k+ - r_j over w_k-) / 2, the
  off-diagonal of S; the off-axis readings of each face are in its quality record. Tilt and
  coupling cannot be told apart from six faces alone (``face_pair_geometry``);
* misalignment, signed (reference default): mean of (r_j - o_j) over the two windows where the
  other axes point up (= (M_ji + M_jl) / 2); absolute (paper): mean of |r_j - o_j| over the four
  non-gravity windows; also the reference's absolute-over-"up"-windows as a diagnostic;
* noise_k = 2 x SD of axis k over its +1 g window (paper; population SD);
* diagnostics: the classical midpoint offset (m_k+ + m_k-)/2 and the raw window means;
* optionally the full affine model: column k of S = (mean vector over w_k+ - over w_k-) / 2
  (the gains on the diagonal, the coupling off it), o = the face-pair midpoints, correction
  a = S^-1 (r - o).

The correction is a_k = (r_k - o_k) / G_k (g). As an engine estimate (the GGIR form of the
autocalibration, (raw + offset) * scale) it is offset = -o, scale = 1/G, method ``static-6``;
the whole static result rides in ``extra["static"]`` (and so in the store and the MCAP).
A missing face is an error naming it; the reference's silent NaNs only with ``allow_nan``.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Optional

import numpy as np

from stillpoint.engine.core.errors import StillpointError

from ..core.times import iso_utc
from .estimate import STATIC_METHOD, CalibrationEstimate
from .sixface import FACE_WORDS, FACES, FaceSearch, find_faces

# offset rule per search mode (module docstring)
OFFSET_RULE = {"reference": "non-gravity", "paper": "non-gravity", "robust": "midpoint"}
# above this |coupling| a calibration without the full matrix says so: the rest level of the
# norm then moves with posture by up to about 2 |M| (0.5 % -> ~10 mg, far above sensor noise)
COUPLING_NOTE = 0.005
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
    return None if ns is None else iso_utc(ns, "ms")


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
    cross_axis_g: Optional[list] = None  # 3x3 coupling M (rows = measured axes, 0 on the diagonal)
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


def _face_means(acc: np.ndarray, w: dict) -> dict:
    """Mean reading vector of each face's window (NaN where the face is empty)."""
    nan = np.full(3, np.nan)
    return {f: acc[w[f]].mean(axis=0) if w[f].size else nan for f in FACES}


def face_pair_geometry(means: dict) -> dict:
    """What the three face pairs define, from the six face mean vectors (g).

    * ``midpoint_g[k]`` = (r_k(+k) + r_k(-k)) / 2: the offset of axis k (the classical
      six-position midpoint). Coupling does not move it for level holds; a placement tilted by
      theta moves it by at most G (1 - cos theta) / 2 + |M| sin theta (0.08 + 0.35 mg at 1 degree
      and 2 % coupling), the off-axis readings by G sin theta (17 mg per degree);
    * ``half_difference[k]`` = (r_k(+k) - r_k(-k)) / 2: the gain of axis k;
    * ``cross_axis_g[j][k]`` (j != k) = (r_j(+k) - r_j(-k)) / 2: the coupling of axis j to
      gravity along axis k (the off-diagonal term M_jk of S = diag(G) + M); 0 on the diagonal;
    * ``off_axis_pair_mean_g[j][k]`` (j != k) = (r_j(+k) + r_j(-k)) / 2 - midpoint_g[j]: zero for
      exact flips under the linear model whatever the coupling; a placement that is not level
      (tilted table, a face not sitting flat) leaves about G_j sin(theta) here (17 mg per degree).

    Six faces alone cannot separate a tilted placement from coupling: both move the off-axis
    readings, and a tilt that differs between the two holds of a pair enters the half-difference
    as well. Coupling changes sign with the face (it is only in the half-difference); a tilt need
    not, so a non-zero ``off_axis_pair_mean_g`` flags tilt and bounds how much of the coupling
    estimate may be tilt. A second hold of a face turned 180 degrees about the vertical separates
    them: the tilt's share of the off-axis readings changes sign in the device frame, the
    coupling's does not.
    """
    mid, half = np.full(3, np.nan), np.full(3, np.nan)
    cross, pair = np.zeros((3, 3)), np.zeros((3, 3))
    for k, a in enumerate("xyz"):
        up, dn = means["+" + a], means["-" + a]
        mid[k] = (up[k] + dn[k]) / 2.0
        half[k] = (up[k] - dn[k]) / 2.0
    for k, a in enumerate("xyz"):
        up, dn = means["+" + a], means["-" + a]
        for j in range(3):
            if j != k:
                cross[j, k] = (up[j] - dn[j]) / 2.0
                pair[j, k] = (up[j] + dn[j]) / 2.0 - mid[j]
    return {"midpoint_g": mid, "half_difference": half, "cross_axis_g": cross,
            "off_axis_pair_mean_g": pair}


OFFSET_RULES = ("non-gravity", "midpoint")


def estimate_from_windows(acc_g: np.ndarray, windows: dict, *, full_matrix: bool = False,
                          offset_rule: str = "non-gravity") -> dict:
    """The formulas of §2 on given windows (face -> indices); NaN where a face is empty.

    ``offset_rule``: "non-gravity" (the paper and the reference code: axis j's mean over the
    pooled samples of the four windows where it is not the gravity axis) or "midpoint" (the face
    pair's own midpoint, :func:`face_pair_geometry`). The pooled mean cancels the coupling only
    when the +i and -i windows hold equally many samples: with holds of unequal length a 1 %
    coupling moves it by several tenths of a mg to a few mg; the midpoint is free of it.
    """
    if offset_rule not in OFFSET_RULES:
        raise ValueError(f"offset_rule must be one of {OFFSET_RULES}, not {offset_rule!r}")
    acc = np.asarray(acc_g, np.float64)
    w = {f: np.asarray(windows.get(f, ()), np.int64) for f in FACES}
    axes = "xyz"
    pooled, gain, mis_s, mis_abs, mis_abs_up, noise, raw_up, raw_down = ([] for _ in range(8))
    with np.errstate(invalid="ignore", divide="ignore"):
        geo = face_pair_geometry(_face_means(acc, w))
        for j, a in enumerate(axes):
            others = [b for b in axes if b != a]
            png = _pool(w["+" + others[0]], w["+" + others[1]])
            nng = _pool(w["-" + others[0]], w["-" + others[1]])
            non_g = _pool(png, nng)
            pooled.append(_mean(acc[non_g, j]))
        offset = list(pooled) if offset_rule == "non-gravity" else \
            [float(v) for v in geo["midpoint_g"]]
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
    out = {"offset_g": offset, "gain": gain, "misalignment_signed_g": mis_s,
           "misalignment_abs_g": mis_abs, "noise_g": noise,
           "cross_axis_g": geo["cross_axis_g"].tolist(),
           "diagnostics": {"offset_rule": offset_rule,
                           "midpoint_offset_g": geo["midpoint_g"].tolist(),
                           "non_gravity_offset_g": pooled,
                           "off_axis_pair_mean_g": geo["off_axis_pair_mean_g"].tolist(),
                           "misalignment_abs_up_g": mis_abs_up,
                           "raw_mean_up_g": raw_up, "raw_mean_down_g": raw_down}}
    if full_matrix:
        # the affine model r = S u + o: S = diag(half-differences) + the coupling, o = the pair
        # midpoints (not the mean of all six windows: the off-axis readings carry any tilt of the
        # placements at first order, the midpoints at second order)
        s = np.diag(geo["half_difference"]) + geo["cross_axis_g"]
        out["matrix"] = s.tolist()
        out["matrix_offset_g"] = geo["midpoint_g"].tolist()
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
    est = estimate_from_windows(acc, search.windows, full_matrix=full_matrix and not missing,
                                offset_rule=OFFSET_RULE.get(mode, "non-gravity"))
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
        sinv = np.linalg.inv(np.asarray(est["matrix"])) if "matrix" in est else None
        for f in FACES:
            mean = acc[search.windows[f]].mean(axis=0)
            m = (mean - o) / g if sinv is None else sinv @ (mean - np.asarray(est["matrix_offset_g"]))
            k = "xyz".index(f[1])
            sign = 1.0 if f[0] == "+" else -1.0
            faces[f]["corrected_norm_error_g"] = float(abs(np.linalg.norm(m) - 1.0))
            off = mean - o  # offset-removed off-axis readings
            faces[f]["off_axis_g"] = {a: float(off[i]) for i, a in enumerate("xyz") if i != k}
            faces[f]["corrected_tilt_deg"] = float(np.degrees(np.arccos(
                np.clip(sign * m[k] / np.linalg.norm(m), -1.0, 1.0))))
    status = "ok" if not missing else "incomplete"
    warnings = list(search.warnings)
    cross = np.asarray(est["cross_axis_g"])
    if not missing and not full_matrix and np.nanmax(np.abs(cross)) > COUPLING_NOTE:
        j, k = np.unravel_index(int(np.nanargmax(np.abs(cross))), cross.shape)
        warnings.append(
            f"cross-axis coupling up to {abs(cross[j, k]) * 100:.2f} % ({'xyz'[j]} reads "
            f"{cross[j, k] * 1000:+.1f} mg per g along {'xyz'[k]}): offset and gain are not "
            "affected, but the corrected norm at rest moves with the posture; the full matrix "
            "(--full-matrix) corrects it, unless the faces were held tilted (see "
            "diagnostics.off_axis_pair_mean_g)")
    if missing:
        warnings.append("reference behaviour: NaN gain for the axes of the missing faces; offsets "
                        "of the other axes come from fewer than four orientations")
    return StaticCalibration(
        offset_g=est["offset_g"], gain=est["gain"],
        misalignment_signed_g=est["misalignment_signed_g"],
        misalignment_abs_g=est["misalignment_abs_g"], noise_g=est["noise_g"], mode=mode,
        status=status, faces=faces, attempts=search.attempts, warnings=warnings,
        diagnostics=est["diagnostics"], cross_axis_g=est["cross_axis_g"], matrix=est.get("matrix"),
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
    from stillpoint.engine.recordings import open_recording
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
