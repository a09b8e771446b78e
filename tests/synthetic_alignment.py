"""Synthetic two-device recordings with known clocks, for alignment tests and the seed table.

One person's activity (walking-like bouts of random cadence and intensity between sedentary
stretches) seen by two devices worn at different sites (different gains, harmonic mix and noise),
each sampling on its own clock:

    C_dev(tau) = tau + offset + skew * tau + kappa * integral (T_dev - T0)^2 dtau - halt losses

(tau = true time, s). A halt stops a device's sampling *and* its clock for a while, so its later
timestamps lag by the halt's length (the AX3 behaviour in Brønd et al. 2021). Blocks are generated
one chunk at a time (bounded memory) and carry per-unit temperatures. This is a test double for the
real simulator (engine/sim), kept small and fast; ``truth_offset_s`` gives the exact answer.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Iterator, Optional

import numpy as np

from stillpoint.drivers.constants import RTC_CRYSTAL_TURNOVER_C
from stillpoint.engine.core.blocks import Block, DeviceInfo, QCReport

COUNTS_PER_G = 256.0  # AX3 at +-8 g: 1/256 g per count
T_START_NS = 1_700_000_000 * 1_000_000_000
UNIT = 120  # samples per unit (like a .cwa sector)


@dataclass
class DeviceClock:
    offset_s: float = 0.0  # clock minus true time at tau = 0
    skew_ppm: float = 0.0
    temp_ppm_per_c2: float = 0.0  # 0 = temperature-independent crystal
    halt_at_s: Optional[float] = None  # true time the halt starts
    halt_s: float = 0.0


@dataclass
class ActivityPlan:
    """Bouts on the true time axis: (start, end, amplitude g, cadence Hz, phase)."""

    bouts: np.ndarray  # (k, 5)

    @staticmethod
    def random(rng: np.random.Generator, duration_s: float, active_fraction: float = 0.3,
               sedentary_days: Optional[list] = None, start_hour: float = 8.0) -> "ActivityPlan":
        rows = []
        t = float(rng.uniform(0, 120))
        while t < duration_s:
            day = int(t // 86400)
            hour = ((t + start_hour * 3600) % 86400) / 3600
            asleep = hour < 6 or hour >= 23
            sedentary = sedentary_days is not None and day in sedentary_days
            dur = float(rng.lognormal(np.log(90), 1.0))
            dur = min(dur, 1200.0)
            p_active = 0.0 if asleep else (0.03 if sedentary else active_fraction)
            if rng.uniform() < p_active:
                rows.append((t, t + dur, float(rng.uniform(0.1, 0.8)),
                             float(rng.uniform(1.5, 2.2)), float(rng.uniform(0, 2 * np.pi))))
                t += dur
            t += float(rng.lognormal(np.log(200), 1.0))
        return ActivityPlan(np.array(rows, dtype=np.float64).reshape(-1, 5))

    def magnitude(self, tau: np.ndarray, site: int) -> np.ndarray:
        """‖a‖ − 1 (g) at true times tau for a site (0 = reference site, 1 = other site)."""
        out = np.zeros(tau.shape)
        if self.bouts.size == 0 or tau.size == 0:
            return out
        starts = self.bouts[:, 0]
        i = np.searchsorted(starts, tau, side="right") - 1
        ok = i >= 0
        ii = np.where(ok, i, 0)
        b = self.bouts[ii]
        inside = ok & (tau < b[:, 1])
        if not inside.any():
            return out
        tt = tau[inside] - b[inside, 0]
        amp, cad, ph = b[inside, 2], b[inside, 3], b[inside, 4]
        # cadence wanders slowly; intensity is modulated within a bout
        phase = ph + 2 * np.pi * cad * tt + 0.6 * np.sin(2 * np.pi * tt / 23.0 + ph)
        env = amp * (1 + 0.4 * np.sin(2 * np.pi * tt / (37.0 + 10 * ph) + 2 * ph))
        env *= np.clip(tt / 2.0, 0, 1) * np.clip((b[inside, 1] - tau[inside]) / 2.0, 0, 1)
        # stride-to-stride variability: a pseudo-random gain per step cycle (shared by both sites)
        cycle = np.floor(phase / (2 * np.pi))
        h = np.sin(cycle * 12.9898 + ph * 78.233) * 43758.5453
        env *= 0.55 + 0.9 * (h - np.floor(h))
        # irregular bouts (odd cadence parameter digit): non-periodic sum of sinusoids instead
        irregular = (np.floor(cad * 100) % 2) == 1
        if irregular.any():
            x = tt[irregular]
            p2 = ph[irregular]
            phase[irregular] = (np.sin(2 * np.pi * 0.31 * x + p2) + np.sin(2 * np.pi * 0.87 * x + 2 * p2)
                                + np.sin(2 * np.pi * 1.73 * x + 3 * p2)) * 2.0
        if site == 0:
            w = np.sin(phase) + 0.35 * np.sin(2 * phase + 0.4)
        else:
            w = 0.8 * np.sin(phase) + 0.5 * np.sin(2 * phase + 0.4)
        out[inside] = env * w
        return out


def temperature_profile(tau: np.ndarray, site: int, seed: int) -> np.ndarray:
    """Skin-worn device temperature (°C): diurnal cycle plus site offset and slow wander."""
    ph = (seed % 97) / 97 * 2 * np.pi
    base = 31.0 if site == 0 else 27.0
    swing = 3.0 if site == 0 else 7.0
    return (base + swing * np.sin(2 * np.pi * tau / 86400.0 + ph + site)
            + 1.5 * np.sin(2 * np.pi * tau / 20000.0 + 3 * ph + site))


@dataclass
class SyntheticPair:
    """A reference and another device recording the same person (see module doc)."""

    seed: int = 0
    duration_s: float = 86400.0
    rate_ref: float = 50.0
    rate_other: float = 50.0
    clock_ref: DeviceClock = field(default_factory=DeviceClock)
    clock_other: DeviceClock = field(default_factory=DeviceClock)
    noise_g: float = 0.008
    active_fraction: float = 0.3
    sedentary_days: Optional[list] = None
    chunk_s: float = 900.0
    start_hour: float = 8.0  # local time of day at the start (nights are sedentary)

    def __post_init__(self):
        rng = np.random.default_rng(self.seed)
        self.plan = ActivityPlan.random(rng, self.duration_s + 600, self.active_fraction,
                                        self.sedentary_days, self.start_hour)
        # clock tables on a coarse true-time grid (temperature integral, halts)
        self._tau = np.arange(-600.0, max(self.duration_s, 7 * 86400.0) + 3600.0, 30.0)
        self._clock = [self._clock_table(c, s) for s, c in enumerate((self.clock_ref,
                                                                      self.clock_other))]

    def _clock_table(self, c: DeviceClock, site: int) -> np.ndarray:
        tau = self._tau
        eps = c.skew_ppm * 1e-6 + c.temp_ppm_per_c2 * 1e-6 * (
            temperature_profile(tau, site, self.seed) - RTC_CRYSTAL_TURNOVER_C) ** 2
        integ = np.concatenate([[0.0], np.cumsum(0.5 * (eps[1:] + eps[:-1]) * np.diff(tau))])
        integ -= np.interp(0.0, tau, integ)
        clock = tau + c.offset_s + integ
        if c.halt_at_s is not None and c.halt_s > 0:
            h0, h1 = c.halt_at_s, c.halt_at_s + c.halt_s
            clock = clock - np.clip(tau - h0, 0, h1 - h0)  # clock frozen during the halt
        return clock

    def clock(self, site: int, tau) -> np.ndarray:
        return np.interp(tau, self._tau, self._clock[site])

    def true_time(self, site: int, c) -> np.ndarray:
        """True time of clock reading c (during a halt: its end)."""
        tab = self._clock[site]
        # make strictly increasing for inversion (halt plateau -> its last point)
        return np.interp(c, tab + np.arange(tab.size) * 1e-12, self._tau)

    def first_sample_clock(self, site: int) -> float:
        return float(np.ceil(self.clock(site, 0.0) * 1000) / 1000)

    def truth_offset_s(self, t_ref_s) -> np.ndarray:
        """Exact other-minus-reference clock offset at reference times (s since ref start)."""
        c_ref = self.first_sample_clock(0) + np.asarray(t_ref_s, dtype=np.float64)
        tau = self.true_time(0, c_ref)
        return self.clock(1, tau) - c_ref

    def truth(self) -> dict:
        d0 = float(self.truth_offset_s(0.0))
        d7 = float(self.truth_offset_s(7 * 86400.0))
        return {"initial_offset_s": d0, "drift_day7_s": d7 - d0}

    def t0_ns(self, site: int) -> int:
        return T_START_NS + int(round(self.first_sample_clock(site) * 1e9))

    def blocks(self, site: int) -> Iterator[Block]:
        rate = self.rate_ref if site == 0 else self.rate_other
        rng = np.random.default_rng(self.seed * 7919 + site)
        c0 = self.first_sample_clock(site)
        c_end = float(self.clock(site, self.duration_s))
        n_total = int((c_end - c0) * rate)
        per = int(self.chunk_s * rate) // UNIT * UNIT
        u = np.array([0.3, 0.5, 0.81]) if site == 0 else np.array([0.9, -0.2, 0.39])
        u = u / np.linalg.norm(u)
        for k0 in range(0, n_total, per):
            k = np.arange(k0, min(n_total, k0 + per))
            c = c0 + k / rate
            tau = self.true_time(site, c)
            m = self.plan.magnitude(tau, site) * (1.0 if site == 0 else 1.3)
            m += rng.normal(0, self.noise_g, m.size)
            a = (1.0 + m)[:, None] * u[None, :]
            counts = np.round(a * COUNTS_PER_G).astype(np.int16)
            starts = np.arange(0, k.size, UNIT, dtype=np.int64)
            temps = temperature_profile(tau[starts], site, self.seed)
            yield Block(time_ns=T_START_NS + np.round(c * 1e9).astype(np.int64), accel=counts,
                        accel_counts_per_g=np.full(3, COUNTS_PER_G), accel_zero=np.zeros(3),
                        unit_index=(k0 + starts) // UNIT, unit_sequence=(k0 + starts) // UNIT,
                        unit_start=starts, temperature_c=temps,
                        temperature_raw=np.full(starts.size, -1, np.int32),
                        light=np.zeros(starts.size, np.int32), battery_v=np.full(starts.size, np.nan),
                        events=np.zeros(starts.size, np.uint8), first_sample=int(k0))

    def source(self, site: int) -> "SyntheticSource":
        return SyntheticSource(self, site)


class SyntheticSource:
    """Source protocol over one device of a SyntheticPair."""

    def __init__(self, pair: SyntheticPair, site: int):
        self.pair = pair
        self.site = site
        rate = pair.rate_ref if site == 0 else pair.rate_other
        self.info = DeviceInfo(device_type="AX3", device_id=f"SYN{pair.seed}-{site}",
                               session_id=site, firmware="synthetic", sample_rate_nominal=rate,
                               accel_range_g=8.0)
        self.qc = QCReport(unit="sector")

    def __iter__(self):
        return self.pair.blocks(self.site)

    def close(self) -> None:
        pass


def write_cwa(pair: SyntheticPair, site: int, path) -> str:
    """Write one device of the pair as a real AX3 .cwa file (packed, +-8 g) through CwaWriter,
    so tests and benchmarks exercise the real decoder."""
    from stillpoint.drivers.cwa_writer import CwaWriter
    rate = pair.rate_ref if site == 0 else pair.rate_other
    with CwaWriter(path, device_type="AX3", device_id=4000 + 10 * (pair.seed % 1000) + site,
                   session_id=site, rate_hz=rate, range_g=8) as w:
        for b in pair.blocks(site):
            temp = b.temperature_per_sample()
            raw = np.round((temp + 50.0) * 256.0 / 75.0).astype(np.int64)  # [CWA] raw*75/256-50
            w.write(b.time_ns, b.accel.astype(np.int64), temperature_raw=raw)
    return str(path)
