"""Simulated six-orientation calibration sessions (the user's one-minute protocol), in memory or
written as a real AX3/AX6 ``.cwa``.

A session: optional handling before (random wandering orientation and jerks), then the six faces
in any order (repeats allowed), each held for ``hold_s`` on a (possibly tilted) level surface,
separated by hand turns of 1-3 s (smooth rotation between the face directions plus hand jitter on
all axes), then optional handling after. The sensor errors (``StaticErrors``, including symmetric
cross-axis coupling) are applied to the true specific force; the truth records them, the face
order and every hold's time span.

A table that is not level (``table_tilt_deg``) tilts gravity by that angle on every hold; the
device lies on the table at a random yaw each time, so in the device frame the tilt points in a
random direction per hold. The off-axis readings of a hold then carry about sin(tilt) (17 mg per
degree), the gravity axis only 1 - cos(tilt) (0.15 mg at 1 degree). Coupling gives off-axis
readings that change sign with the face; a tilt per hold need not. Six faces alone cannot
separate the two (``engine.calibration.static.face_pair_geometry``): the face-pair midpoints (the
robust offsets) and half-differences (gains) are nearly free of both, the coupling estimate is
not free of tilt.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Optional, Sequence

import numpy as np

from .static_errors import StaticErrors

FACES = ("+x", "-x", "+y", "-y", "+z", "-z")
_DIRS = {"+x": (1, 0, 0), "-x": (-1, 0, 0), "+y": (0, 1, 0), "-y": (0, -1, 0),
         "+z": (0, 0, 1), "-z": (0, 0, -1)}
DEFAULT_START_NS = 1_741_000_000 * 1_000_000_000  # 2025-03-03 (any fixed time)


@dataclass
class SixFaceSession:
    """The generated samples and their truth."""

    time_ns: np.ndarray  # (n,) int64
    accel_g: np.ndarray  # (n, 3) measured (errors applied)
    true_g: np.ndarray  # (n, 3) error-free specific force
    gyro_dps: np.ndarray  # (n, 3)
    fs: float
    errors: StaticErrors
    holds: list  # [{"face", "start_s", "end_s"}]
    face_label: np.ndarray  # (n,) int8: index into FACES, -1 = moving
    settings: dict = field(default_factory=dict)

    def truth(self) -> dict:
        return {"format": "stillpoint.sixface_truth", "fs": self.fs,
                "errors": self.errors.to_dict(), "holds": self.holds, "settings": self.settings}


def _slerp(u0: np.ndarray, u1: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Great-circle interpolation (through a perpendicular direction for opposite vectors)."""
    dot = float(np.clip(np.dot(u0, u1), -1, 1))
    if dot < -0.999:
        mid = np.cross(u0, [0.3, 0.5, 0.8])
        mid /= np.linalg.norm(mid)
        first = s < 0.5
        out = np.empty((s.shape[0], 3))
        out[first] = _slerp(u0, mid, 2 * s[first])
        out[~first] = _slerp(mid, u1, 2 * s[~first] - 1)
        return out
    ang = np.arccos(dot)
    if ang < 1e-9:
        return np.repeat(u0[None], s.shape[0], 0)
    a = np.sin((1 - s) * ang)[:, None] / np.sin(ang)
    b = np.sin(s * ang)[:, None] / np.sin(ang)
    return a * u0 + b * u1


def _smooth_noise(rng, n: int, fs: float, cutoff_hz: float, sd: float) -> np.ndarray:
    """Low-passed white noise (n, 3) with SD about ``sd`` (moving average of ~1/cutoff s)."""
    if n == 0 or sd == 0:
        return np.zeros((n, 3))
    w = max(1, int(fs / cutoff_hz))
    x = rng.standard_normal((n + w, 3))
    c = np.cumsum(x, axis=0)
    y = (c[w:] - c[:-w]) / np.sqrt(w)
    return y[:n] * sd


def simulate_sixface(*, fs: float = 25.0, hold_s=10.0, order: Optional[Sequence[str]] = None,
                     errors: Optional[StaticErrors] = None, seed: int = 1,
                     turn_s=(1.0, 3.0), jitter_g: float = 0.02, pre_s: float = 3.0,
                     post_s: float = 3.0, tilt_deg: float = 0.0, table_tilt_deg: float = 0.0,
                     hold_edge_jitter_g: float = 0.0,
                     start_ns: int = DEFAULT_START_NS, clip_g: Optional[float] = None,
                     turn_profile: str = "smooth") -> SixFaceSession:
    """Generate a session (see the module docstring). ``hold_s``: one value or one per face in
    ``order``; ``order``: default a random permutation of the six faces; ``errors``: default
    ideal; ``tilt_deg``: each hold tilted by a random angle up to this (a face not sitting flat);
    ``table_tilt_deg``: a table tilted by this angle, the device at a random yaw on it per hold
    (the two add); ``hold_edge_jitter_g``: hand jitter on the non-gravity axes in the first and last
    second of each hold (the hand letting go / picking up); ``clip_g``: clip the readings;
    ``turn_profile``: "smooth" (slow approach to the face: smoothstep) or "linear" (constant
    rotation speed, the device set down briskly)."""
    rng = np.random.default_rng(seed)
    errors = errors or StaticErrors.ideal()
    if order is None:
        order = [FACES[i] for i in rng.permutation(6)]
    order = list(order)
    for f in order:
        if f not in _DIRS:
            raise ValueError(f"unknown face {f!r} (one of {FACES})")
    holds_s = np.broadcast_to(np.asarray(hold_s, np.float64), (len(order),))
    pieces_u, pieces_j, pieces_lab = [], [], []
    holds = []
    t = 0.0

    def add(u, jit, lab):
        nonlocal t
        pieces_u.append(u)
        pieces_j.append(jit)
        pieces_lab.append(lab)
        t += u.shape[0] / fs

    # handling before: wander from a random direction to the first face
    prev = rng.standard_normal(3)
    prev /= np.linalg.norm(prev)
    if pre_s > 0:
        n = int(round(pre_s * fs))
        mid = rng.standard_normal(3)
        mid /= np.linalg.norm(mid)
        u = _slerp(prev, mid, np.linspace(0, 1, n))
        add(u, _smooth_noise(rng, n, fs, 3.0, jitter_g * 3), np.full(n, -1, np.int8))
        prev = mid
    for i, f in enumerate(order):
        target = np.asarray(_DIRS[f], np.float64)
        if tilt_deg or table_tilt_deg:
            ax = np.cross(target, rng.standard_normal(3))
            ax /= np.linalg.norm(ax)
            th = np.radians(table_tilt_deg + (rng.uniform(0, tilt_deg) if tilt_deg else 0.0))
            target = target * np.cos(th) + np.cross(ax, target) * np.sin(th)
        n = int(round(rng.uniform(*turn_s) * fs)) if (i or pre_s > 0) else 0
        if n:
            s = np.linspace(0, 1, n + 2)[1:-1]
            if turn_profile == "smooth":
                s = s * s * (3 - 2 * s)
            add(_slerp(prev, target, s), _smooth_noise(rng, n, fs, 4.0, jitter_g),
                np.full(n, -1, np.int8))
        n = int(round(holds_s[i] * fs))
        jit = np.zeros((n, 3))
        if hold_edge_jitter_g and n:
            e = min(int(fs), n // 2)
            k = "xyz".index(f[1])
            for sl in (slice(0, e), slice(n - e, n)):
                j = _smooth_noise(rng, sl.stop - sl.start, fs, 5.0, hold_edge_jitter_g)
                j[:, k] = 0.0
                jit[sl] = j
        holds.append({"face": f, "start_s": t, "end_s": t + n / fs})
        add(np.repeat(target[None], n, 0), jit, np.full(n, FACES.index(f), np.int8))
        prev = target
    if post_s > 0:
        n = int(round(post_s * fs))
        end = rng.standard_normal(3)
        end /= np.linalg.norm(end)
        add(_slerp(prev, end, np.linspace(0, 1, n)), _smooth_noise(rng, n, fs, 3.0, jitter_g * 3),
            np.full(n, -1, np.int8))
    u = np.concatenate(pieces_u)
    true = u + np.concatenate(pieces_j)
    lab = np.concatenate(pieces_lab)
    meas = errors.measure(true, rng)
    if clip_g:
        meas = np.clip(meas, -clip_g, clip_g)
    # angular velocity of the gravity direction (deg/s) plus gyro noise
    du = np.gradient(u, axis=0) * fs
    omega = np.cross(u, du)
    gyro = np.degrees(omega) + rng.standard_normal(u.shape) * 0.3
    n = u.shape[0]
    time_ns = start_ns + np.round(np.arange(n) * (1e9 / fs)).astype(np.int64)
    return SixFaceSession(time_ns, meas, true, gyro, float(fs), errors, holds, lab,
                          {"order": order, "hold_s": holds_s.tolist(), "turn_s": list(turn_s),
                           "jitter_g": jitter_g, "pre_s": pre_s, "post_s": post_s,
                           "tilt_deg": tilt_deg, "table_tilt_deg": table_tilt_deg,
                           "hold_edge_jitter_g": hold_edge_jitter_g,
                           "turn_profile": turn_profile,
                           "seed": seed})


def write_cwa(path, time_ns, accel_g, gyro_dps=None, *, device: str = "ax6", fs: float = 25.0,
              device_id: int = 4242, range_g: int = 8, gyro_range_dps: int = 2000,
              metadata: Optional[dict] = None) -> dict:
    """Write samples as a real ``.cwa`` (AX6 with gyro, or AX3 unpacked) through the project's
    writer, atomically. Returns {"path", "samples", "device_key"}."""
    from stillpoint.drivers.cwa import CwaWriter
    from stillpoint.engine.core.outputs import atomic_output
    kind = device.upper()
    with_gyro = kind == "AX6" and gyro_dps is not None
    with atomic_output(path, what="simulated recording") as f:
        w = CwaWriter(f, device_type=kind, device_id=device_id, session_id=1, rate_hz=fs,
                      range_g=range_g, packed=False,
                      gyro_range_dps=gyro_range_dps if with_gyro else None, metadata=metadata)
        lim = 32767
        a = np.clip(np.round(np.asarray(accel_g) * w.accel_counts_per_g), -lim, lim).astype(np.int16)
        g = None
        if with_gyro:
            g = np.clip(np.round(np.asarray(gyro_dps) / w.gyro_dps_per_count), -lim, lim).astype(np.int16)
        w.write(time_ns, a, gyro_counts=g)
        w.close()
    return {"path": str(path), "samples": int(len(time_ns)), "device_key": f"{kind}-{device_id}"}


def write_sixface(path, session: SixFaceSession, *, device: str = "ax6", device_id: int = 4242,
                  range_g: int = 8, truth_path=None) -> dict:
    """Write a session as ``.cwa`` plus its truth JSON (default ``<stem>.truth.json``)."""
    from pathlib import Path

    from stillpoint.engine.core.outputs import atomic_output
    res = write_cwa(path, session.time_ns, session.accel_g, session.gyro_dps, device=device,
                    fs=session.fs, device_id=device_id, range_g=range_g,
                    metadata={"_sc": "sixface-calibration"})
    p = Path(path)
    tp = Path(truth_path) if truth_path else p.with_name(p.name.split(".")[0] + ".truth.json")
    doc = dict(session.truth(), device_key=res["device_key"], path=str(p))
    with atomic_output(tp, binary=False, what="truth") as f:
        f.write(json.dumps(doc, indent=1) + "\n")
    res["truth"] = str(tp)
    return res
