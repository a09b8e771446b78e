"""Find the six static faces (each axis up and down) in a six-orientation calibration recording.

Pure functions over an (n, 3) array in g at a nominal rate. Three modes:

* ``reference`` - the search of the HBCD release (Oh, Loeb & Smith 2024 reference code),
  reproduced exactly: per axis, candidate samples whose gravity-axis reading is strictly inside
  the band (0.9, 1.1) g (or its negative), the first run of ``W = fs * window`` consecutive
  candidates (scanned in steps of 10 list positions) whose SD on that axis is below 0.02 g;
  band widening by 0.05 g (four bands, the last [0.75, 1.25] reached through float rounding),
  then window shrinking by 1 s down to 1 s, then give-up (empty window). Its quirk is kept: when
  the scan ends exactly at the end of the candidate list the last sub-list is returned untested.
* ``paper`` - the same schedule with the paper's SD cut-off 0.01 g; every window is tested (no
  untested window).
* ``robust`` - stillness on all three axes (1-s rolling SD of each axis below the cut-off),
  each still stretch classified by its dominant axis and sign, the longest stretch per face
  (not the first), trimmed by 0.5 s at both ends, with per-face quality (duration, SD, |norm - 1|,
  angle between the dominant axis and the measured gravity vector).

The result is a :class:`FaceSearch`: sample indices per face (empty when not found), the band
and window length used, and every attempt made (the fallback steps).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np

FACES = ("+x", "-x", "+y", "-y", "+z", "-z")  # "+x": x axis pointing up (reads +1 g)
FACE_WORDS = {"+x": "x axis up", "-x": "x axis down", "+y": "y axis up", "-y": "y axis down",
              "+z": "z axis up", "-z": "z axis down"}
MODES = ("reference", "paper", "robust")

# reference-code defaults (Oh et al. 2024 reference implementation, HEAD; spec §1.2)
BAND_G = (0.9, 1.1)
WINDOW_S = 5
SD_CUT_REFERENCE_G = 0.02
SD_CUT_PAPER_G = 0.01  # paper §3.3
SCAN_STEP = 10  # list positions, independent of fs
WIDEN_G = 0.05
WIDEN_LIMITS = (0.75, 1.25)
# robust mode
ROBUST_SD_CUT_G = 0.02
ROBUST_TRIM_S = 0.5
ROBUST_MIN_HOLD_S = 1.0
ROBUST_NORM_TOL_G = 0.3  # |norm - 1| of a hold (offsets up to ~0.2 g must still qualify)
ROBUST_DOMINANT_MIN_G = 0.7  # the dominant axis must carry most of gravity


@dataclass
class FaceSearch:
    """Where each face was found. ``windows[face]``: sample indices (empty: not found)."""

    mode: str
    fs: float
    windows: dict
    info: dict  # face -> {"band": [lo, hi], "window_s": ..., "tested": bool, ...quality}
    attempts: list = field(default_factory=list)  # every (axis, band, window) tried
    warnings: list = field(default_factory=list)

    @property
    def missing(self) -> list:
        return [f for f in FACES if len(self.windows.get(f, ())) == 0]


# ----------------------------------------------------------------------------- reference scan
def _scan(values: np.ndarray, cands: np.ndarray, w: int, sd_cut: float, step: int,
          untested_quirk: bool):
    """First run of ``w`` consecutive candidate indices (list positions 0, step, 2*step, ...)
    whose values have population SD < sd_cut. Returns (indices or None, tested)."""
    n = cands.shape[0]
    if w <= 0:
        return None, False
    starts = np.arange(0, max(n - w, 0), step)  # sub-lists whose end position < n
    if starts.size:
        ends = starts + w - 1
        consecutive = (cands[ends] - cands[starts]) == (w - 1)  # sorted unique: no gaps
        ok = np.flatnonzero(consecutive)
        if ok.size:
            v = values[cands]
            c1 = np.concatenate(([0.0], np.cumsum(v - v.mean())))
            c2 = np.concatenate(([0.0], np.cumsum((v - v.mean()) ** 2)))
            s = starts[ok]
            m1 = (c1[s + w] - c1[s]) / w
            var = (c2[s + w] - c2[s]) / w - m1 ** 2
            near = np.flatnonzero(var < (sd_cut * 1.001) ** 2)  # exact test below
            for i in near:
                a = int(s[i])
                if np.std(v[a:a + w]) < sd_cut:
                    return cands[a:a + w], True
    last = starts[-1] + step if starts.size else 0  # where the scan stopped
    if untested_quirk and last + w == n:
        return cands[last:last + w], False  # the reference code's untested window (Q1)
    if not untested_quirk and last + w == n and n >= w:
        a = last
        if (cands[a + w - 1] - cands[a]) == w - 1 and np.std(values[cands[a:a + w]]) < sd_cut:
            return cands[a:a + w], True
    return None, False


def _candidates(v: np.ndarray, lo: float, hi: float):
    pos = np.flatnonzero((v < hi) & (v > lo))
    neg = np.flatnonzero((v < -lo) & (v > -hi))
    return pos, neg


def _search_axis(v: np.ndarray, fs_int: int, window_s, sd_cut: float, band, step: int,
                 untested_quirk: bool, axis: str, attempts: list):
    """The reference schedule for one axis: bands, then shorter windows, then give-up."""
    wlen = window_s
    while True:
        lo, hi = float(band[0]), float(band[1])
        w = int(fs_int * wlen)
        first = True
        while True:
            if not first:
                lo -= WIDEN_G
                hi += WIDEN_G
            first = False
            cp, cn = _candidates(v, lo, hi)
            p, tp = _scan(v, cp, w, sd_cut, step, untested_quirk)
            q, tq = _scan(v, cn, w, sd_cut, step, untested_quirk)
            attempts.append({"axis": axis, "band": [lo, hi], "window_s": wlen, "window_samples": w,
                             "found_up": p is not None, "found_down": q is not None})
            if p is not None and q is not None:
                return p, q, (lo, hi), wlen, (tp, tq)
            if not (lo > WIDEN_LIMITS[0] and hi < WIDEN_LIMITS[1]):
                break
        new = int(wlen - 1)
        if new < 1:
            empty = np.zeros(0, np.int64)
            return (p if p is not None else empty, q if q is not None else empty, (lo, hi), wlen,
                    (tp, tq))
        wlen = new


def find_faces_reference(acc_g: np.ndarray, fs: float, *, window_s=WINDOW_S,
                         sd_cut: float = SD_CUT_REFERENCE_G, band=BAND_G, step: int = SCAN_STEP,
                         untested_quirk: bool = True, mode: str = "reference") -> FaceSearch:
    """The reference (or, with ``sd_cut=0.01, untested_quirk=False``, the paper) search."""
    acc = np.asarray(acc_g, np.float64)
    fs_int = int(round(fs))
    windows, info, attempts, warnings = {}, {}, [], []
    for k, ax in enumerate("xyz"):
        p, q, b, wlen, tested = _search_axis(acc[:, k], fs_int, window_s, sd_cut, band, step,
                                             untested_quirk, ax, attempts)
        for face, idx, t in ((f"+{ax}", p, tested[0]), (f"-{ax}", q, tested[1])):
            windows[face] = np.asarray(idx, np.int64)
            if len(idx):
                info[face] = {"band_g": [b[0], b[1]], "window_s": wlen, "samples": int(len(idx)),
                              "tested": bool(t),
                              "sd_g": float(np.std(acc[idx, k]))}
                if not t:
                    warnings.append(f"face {face}: window returned untested by the reference scan "
                                    f"(SD {info[face]['sd_g']:.4f} g)")
            else:
                warnings.append(f"face {face} ({FACE_WORDS[face]}): no window down to 1 s at any band")
    return FaceSearch(mode, float(fs), windows, info, attempts, warnings)


# ----------------------------------------------------------------------------- robust
def _rolling(x: np.ndarray, w: int):
    """Centred rolling mean and population SD over ``w`` samples (NaN where incomplete)."""
    n = x.shape[0]
    mean = np.full(n, np.nan)
    sd = np.full(n, np.nan)
    if n < w:
        return mean, sd
    xc = x - x.mean()
    c1 = np.concatenate(([0.0], np.cumsum(xc)))
    c2 = np.concatenate(([0.0], np.cumsum(xc * xc)))
    m = (c1[w:] - c1[:-w]) / w
    v = np.maximum((c2[w:] - c2[:-w]) / w - m * m, 0.0)
    h = w // 2
    mean[h:h + n - w + 1] = m + x.mean()
    sd[h:h + n - w + 1] = np.sqrt(v)
    return mean, sd


def find_faces_robust(acc_g: np.ndarray, fs: float, *, sd_cut: float = ROBUST_SD_CUT_G,
                      trim_s: float = ROBUST_TRIM_S, min_hold_s: float = ROBUST_MIN_HOLD_S,
                      norm_tol: float = ROBUST_NORM_TOL_G,
                      dominant_min: float = ROBUST_DOMINANT_MIN_G) -> FaceSearch:
    acc = np.asarray(acc_g, np.float64)
    n = acc.shape[0]
    w = max(int(round(fs)), 3)
    means, sds = zip(*(_rolling(acc[:, k], w) for k in range(3)))
    mean = np.stack(means, 1)
    sd = np.stack(sds, 1)
    still = np.all(sd < sd_cut, axis=1)
    absm = np.abs(np.nan_to_num(mean))
    dom = np.argmax(absm, axis=1)
    domv = mean[np.arange(n), dom] if n else np.zeros(0)
    norm = np.linalg.norm(np.nan_to_num(mean), axis=1)
    valid = still & (np.abs(domv) > dominant_min) & (np.abs(norm - 1.0) < norm_tol)
    label = np.where(valid, dom * 2 + (domv < 0), -1)
    # runs of a constant label
    edges = np.flatnonzero(np.diff(label)) + 1
    starts = np.concatenate(([0], edges))
    ends = np.concatenate((edges, [n]))
    trim = int(round(trim_s * fs))
    min_len = int(np.ceil(min_hold_s * fs))
    windows, info, warnings = {}, {}, []
    holds = {f: [] for f in FACES}
    for a, b in zip(starts, ends):
        lab = int(label[a]) if n else -1
        if lab < 0:
            continue
        a2, b2 = int(a) + trim, int(b) - trim
        if b2 - a2 < min_len:
            continue
        face = FACES[lab]
        holds[face].append((a2, b2, float(np.mean(np.std(acc[a2:b2], axis=0)))))
    for face in FACES:
        k = "xyz".index(face[1])
        if not holds[face]:
            windows[face] = np.zeros(0, np.int64)
            warnings.append(f"face {face} ({FACE_WORDS[face]}): no still hold of at least "
                            f"{min_hold_s:g} s (after trimming {trim_s:g} s at each end)")
            continue
        a, b, _ = max(holds[face], key=lambda h: (h[1] - h[0], -h[2]))
        idx = np.arange(a, b, dtype=np.int64)
        windows[face] = idx
        m = acc[a:b].mean(axis=0)
        sign = 1.0 if face[0] == "+" else -1.0
        cosang = np.clip(sign * m[k] / np.linalg.norm(m), -1.0, 1.0)
        info[face] = {"window_s": (b - a) / fs, "samples": int(b - a), "tested": True,
                      "sd_g": float(np.std(acc[a:b, k])),
                      "sd_axes_g": [float(x) for x in np.std(acc[a:b], axis=0)],
                      "norm_error_g": float(abs(np.linalg.norm(m) - 1.0)),
                      "angle_deg": float(np.degrees(np.arccos(cosang))),
                      "holds_found": len(holds[face])}
    return FaceSearch("robust", float(fs), windows, info, [], warnings)


def find_faces(acc_g: np.ndarray, fs: float, mode: str = "reference", *, window_s=None,
               sd_cut: Optional[float] = None) -> FaceSearch:
    """Find the six faces; see the module docstring for ``mode``."""
    if mode == "reference":
        return find_faces_reference(acc_g, fs, window_s=window_s or WINDOW_S,
                                    sd_cut=sd_cut or SD_CUT_REFERENCE_G)
    if mode == "paper":
        return find_faces_reference(acc_g, fs, window_s=window_s or WINDOW_S,
                                    sd_cut=sd_cut or SD_CUT_PAPER_G, untested_quirk=False,
                                    mode="paper")
    if mode == "robust":
        return find_faces_robust(acc_g, fs, sd_cut=sd_cut or ROBUST_SD_CUT_G)
    raise ValueError(f"mode must be one of {MODES}, not {mode!r}")
