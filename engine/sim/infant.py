"""Simulated infant ankle recordings with kicks as truth (spec static-calibration.md §5.2), in
memory or written as a real AX6 (or AX3) ``.cwa``, chunk by chunk (72 h in bounded memory).

* Postures: piecewise-constant gravity direction in the ankle-sensor frame (dwell 1-10 min,
  at least 3 distinct), joined by 2-s rolls.
* Kicks: biphasic linear-acceleration pulses (one sine cycle, first lobe sign random) mostly
  along the local gravity direction plus a smaller perpendicular part; 0.23-0.5 s; peak
  2-7 m/s^2; a simultaneous half-sine angular-velocity pulse (1-4 rad/s) about an axis
  perpendicular to the motion; exponential intervals with a 1-s refractory period.
* Sleep blocks (no kicks, gyro noise only); optional negative controls: perpendicular-only
  pulses, pulses without rotation, and rhythmic chains of 70 (removed by the cycle filter) and
  of 30 pulses (kept) with 0.02-s gaps.
* Sensor errors (``StaticErrors``) on the accelerometer; a device clock skew (ppm) on the written
  timestamps (left/right pairs drift apart by a few seconds over 72 h).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from .sixface import DEFAULT_START_NS, write_cwa
from .static_errors import StaticErrors

G_MS2 = 9.80665
ROLL_S = 2.0
GYRO_NOISE_DPS = 0.5
KINDS = ("kick", "perpendicular", "no_gyro", "rhythmic")


@dataclass
class InfantSim:
    """A deterministic infant recording: events drawn up front, samples rendered on demand."""

    fs: float
    duration_s: float
    errors: StaticErrors
    seed: int
    postures: np.ndarray  # (p, 3) unit gravity directions
    posture_start_s: np.ndarray  # (p,)
    events: dict  # arrays: onset_s, dur_s, amp_g, sign, kind, gyro_rad_s, dir (k,3), axis (k,3)
    sleep_blocks: list  # [(start_s, end_s)]
    clock_skew_ppm: float = 0.0
    start_ns: int = DEFAULT_START_NS
    settings: dict = field(default_factory=dict)

    @property
    def n(self) -> int:
        return int(round(self.duration_s * self.fs))

    # ------------------------------------------------------------------ rendering
    def _gravity(self, t: np.ndarray) -> np.ndarray:
        i = np.searchsorted(self.posture_start_s, t, side="right") - 1
        i = np.clip(i, 0, len(self.postures) - 1)
        u = self.postures[i].copy()
        # roll from the previous posture during the first ROLL_S of each posture
        since = t - self.posture_start_s[i]
        roll = (since < ROLL_S) & (i > 0)
        if np.any(roll):
            s = since[roll] / ROLL_S
            s = s * s * (3 - 2 * s)
            prev = self.postures[i[roll] - 1]
            v = prev * (1 - s)[:, None] + u[roll] * s[:, None]
            u[roll] = v / np.linalg.norm(v, axis=1, keepdims=True)
        return u

    def render(self, k0: int, k1: int, *, with_errors: bool = True):
        """Samples k0..k1-1: (true time s, true g, measured g, gyro deg/s)."""
        k = np.arange(k0, k1)
        t = k / self.fs
        true = self._gravity(t)
        gyro = np.zeros((k.size, 3))
        ev = self.events
        on, dur = ev["onset_s"], ev["dur_s"]
        sel = np.flatnonzero((on + dur > t[0] - 1.0 / self.fs) & (on < t[-1] + 1.0 / self.fs)) \
            if k.size else np.zeros(0, np.int64)
        if sel.size:
            first = np.ceil(on[sel] * self.fs).astype(np.int64)
            last = np.floor((on[sel] + dur[sel]) * self.fs).astype(np.int64)
            first = np.maximum(first, k0)
            last = np.minimum(last, k1 - 1)
            cnt = np.maximum(last - first + 1, 0)
            which = np.repeat(sel, cnt)
            idx = np.concatenate([np.arange(a, b + 1) for a, b in zip(first, last) if b >= a]) \
                if cnt.sum() else np.zeros(0, np.int64)
            if idx.size:
                ph = (idx / self.fs - on[which]) / dur[which]
                lin = (ev["amp_g"][which] * ev["sign"][which] * np.sin(2 * np.pi * ph))[:, None] \
                    * ev["dir"][which]
                np.add.at(true, idx - k0, lin)
                w = (ev["gyro_rad_s"][which] * np.sin(np.pi * ph))[:, None] * ev["axis"][which]
                np.add.at(gyro, idx - k0, np.degrees(w))
        rng = np.random.default_rng((self.seed, 7, k0))
        gyro += rng.standard_normal(gyro.shape) * GYRO_NOISE_DPS
        meas = self.errors.measure(true, rng) if with_errors else true
        return t, true, meas, gyro

    def device_time_ns(self, t_s: np.ndarray) -> np.ndarray:
        return self.start_ns + np.round(t_s * (1.0 + self.clock_skew_ppm * 1e-6) * 1e9).astype(np.int64)

    def arrays(self, *, with_errors: bool = True):
        """The whole recording in memory: (time_ns, measured g, true g, gyro dps)."""
        t, true, meas, gyro = self.render(0, self.n, with_errors=with_errors)
        return self.device_time_ns(t), meas, true, gyro

    def truth(self) -> dict:
        ev = self.events
        kicks = [{"onset_s": float(ev["onset_s"][i]), "end_s": float(ev["onset_s"][i] + ev["dur_s"][i]),
                  "first_lobe": int(ev["sign"][i]), "kind": KINDS[int(ev["kind"][i])],
                  "peak_ms2": float(ev["amp_g"][i] * G_MS2),
                  "posture": int(np.searchsorted(self.posture_start_s, ev["onset_s"][i], "right") - 1)}
                 for i in range(len(ev["onset_s"]))]
        return {"format": "stillpoint.infant_truth", "fs": self.fs, "duration_s": self.duration_s,
                "errors": self.errors.to_dict(), "clock_skew_ppm": self.clock_skew_ppm,
                "postures": self.postures.tolist(), "posture_start_s": self.posture_start_s.tolist(),
                "sleep_blocks": self.sleep_blocks, "kicks": kicks,
                "kick_count": int(np.sum(ev["kind"] == 0)), "settings": self.settings}


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _perp(u: np.ndarray, rng) -> np.ndarray:
    r = rng.standard_normal(u.shape)
    r -= np.sum(r * u, axis=-1, keepdims=True) * u
    return _unit(r)


def make_infant(*, minutes: float = 20.0, fs: float = 25.0, seed: int = 1,
                errors: Optional[StaticErrors] = None, n_postures: Optional[int] = None,
                mean_interval_s: float = 4.0, refractory_s: float = 1.0,
                sleep_blocks=(), controls: bool = False, clock_skew_ppm: float = 0.0,
                posture_dwell_s=(60.0, 600.0), start_ns: int = DEFAULT_START_NS) -> InfantSim:
    """Draw an infant recording (module docstring). ``sleep_blocks``: [(start_min, length_min)]."""
    rng = np.random.default_rng((seed, 11))
    dur = float(minutes) * 60.0
    # postures
    starts, dirs = [0.0], []
    while starts[-1] < dur:
        starts.append(starts[-1] + rng.uniform(*posture_dwell_s))
    starts = np.asarray(starts[:-1])
    p = len(starts) if n_postures is None else int(n_postures)
    if n_postures is not None:
        starts = np.linspace(0, dur, p, endpoint=False)
    base = _unit(rng.standard_normal((max(p, 3), 3)))
    dirs = base[:p] if p >= 1 else base[:1]
    # kicks: exponential intervals with a refractory period, none in sleep
    sleep = [(a * 60.0, (a + b) * 60.0) for a, b in sleep_blocks]
    n_guess = int(dur / (mean_interval_s + refractory_s) * 1.5) + 10
    gaps = refractory_s + rng.exponential(mean_interval_s, n_guess)
    onset = np.cumsum(gaps)
    while onset[-1] < dur:  # pragma: no cover - very unlikely with the 1.5x margin
        onset = np.concatenate((onset, onset[-1] + np.cumsum(refractory_s + rng.exponential(mean_interval_s, n_guess))))
    kd = rng.uniform(0.23, 0.5, onset.size)
    keep = onset + kd < dur - 1.0
    for a, b in sleep:
        keep &= ~((onset + kd > a) & (onset < b))
    onset, kd = onset[keep], kd[keep]
    kind = np.zeros(onset.size, np.int8)
    amp = rng.uniform(2.0, 7.0, onset.size) / G_MS2
    if controls:
        extra_on, extra_d, extra_kind, extra_amp = [], [], [], []
        t = dur * 0.15
        for kd_kind in (1, 2):  # perpendicular-only, no rotation: 20 each
            for _ in range(20):
                extra_on.append(t)
                extra_d.append(0.35)
                extra_kind.append(kd_kind)
                extra_amp.append(4.0 / G_MS2)
                t += 2.5
        for chain in (70, 30):  # rhythmic chains, back to back (0.02 s gaps)
            for _ in range(chain):
                extra_on.append(t)
                extra_d.append(0.3)
                extra_kind.append(3)
                extra_amp.append(4.0 / G_MS2)
                t += 0.32
            t += 15.0
        eo = np.asarray(extra_on)
        # the control block replaces the kicks it overlaps
        clash = np.zeros(onset.size, bool)
        clash |= (onset + kd > eo.min() - 2.0) & (onset < eo.max() + 2.0)
        onset, kd, kind, amp = onset[~clash], kd[~clash], kind[~clash], amp[~clash]
        onset = np.concatenate((onset, eo))
        kd = np.concatenate((kd, extra_d))
        kind = np.concatenate((kind, np.asarray(extra_kind, np.int8)))
        amp = np.concatenate((amp, extra_amp))
        order = np.argsort(onset, kind="stable")
        onset, kd, kind, amp = onset[order], kd[order], kind[order], amp[order]
    m = onset.size
    pi = np.clip(np.searchsorted(starts, onset, side="right") - 1, 0, len(dirs) - 1)
    u = dirs[pi]
    perp = _perp(u, rng)
    beta = np.radians(rng.uniform(10, 30, m))
    direction = np.cos(beta)[:, None] * u + np.sin(beta)[:, None] * perp
    direction[kind == 1] = perp[kind == 1]
    motion_perp = _unit(np.cross(direction, _perp(direction, rng)))
    axis = _unit(np.cross(direction, motion_perp))
    gyro = rng.uniform(1.0, 4.0, m)
    gyro[kind == 2] = 0.0
    sign = rng.choice([-1.0, 1.0], m)
    events = {"onset_s": onset, "dur_s": kd, "amp_g": amp, "sign": sign, "kind": kind,
              "gyro_rad_s": gyro, "dir": direction, "axis": axis}
    return InfantSim(float(fs), dur, errors or StaticErrors.ideal(), seed, dirs, starts, events,
                     [list(b) for b in sleep], clock_skew_ppm, start_ns,
                     {"minutes": minutes, "mean_interval_s": mean_interval_s,
                      "refractory_s": refractory_s, "controls": controls, "seed": seed})


def write_infant(path, sim: InfantSim, *, device: str = "ax6", device_id: int = 5001,
                 range_g: int = 8, truth_path=None, chunk_s: float = 3600.0) -> dict:
    """Write the recording as ``.cwa`` chunk by chunk (plus its truth JSON)."""
    from pathlib import Path

    from stillpoint.drivers.cwa import CwaWriter
    from stillpoint.engine.core.outputs import atomic_output
    kind = device.upper()
    with_gyro = kind == "AX6"
    step = max(1, int(chunk_s * sim.fs))
    with atomic_output(path, what="simulated recording") as f:
        w = CwaWriter(f, device_type=kind, device_id=device_id, session_id=1, rate_hz=sim.fs,
                      range_g=range_g, packed=False, gyro_range_dps=2000 if with_gyro else None,
                      metadata={"_sc": "infant-ankle", "_p": "ankle"})
        lim = 32767
        for k0 in range(0, sim.n, step):
            t, _, meas, gyro = sim.render(k0, min(sim.n, k0 + step))
            a = np.clip(np.round(meas * w.accel_counts_per_g), -lim, lim).astype(np.int16)
            g = (np.clip(np.round(gyro / w.gyro_dps_per_count), -lim, lim).astype(np.int16)
                 if with_gyro else None)
            w.write(sim.device_time_ns(t), a, gyro_counts=g)
        w.close()
    p = Path(path)
    tp = Path(truth_path) if truth_path else p.with_name(p.name.split(".")[0] + ".truth.json")
    with atomic_output(tp, binary=False, what="truth") as f:
        f.write(json.dumps(dict(sim.truth(), device_key=f"{kind}-{device_id}", path=str(p))) + "\n")
    return {"path": str(p), "truth": str(tp), "samples": sim.n, "device_key": f"{kind}-{device_id}",
            "kicks": int(np.sum(sim.events["kind"] == 0))}


__all__ = ["InfantSim", "make_infant", "write_infant", "write_cwa"]
