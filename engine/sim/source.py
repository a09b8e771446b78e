"""``SimSource``: the simulator as a Source (engine.core.source), yielding Blocks without a file.

Same samples (counts) as the file ``simulate_recording`` would write with the same arguments;
sample times are the exact device-clock times (a file reproduces them to its resolution).
Units mimic the device's: AX3 packed 120 samples per sector, unpacked 80, AX6 with gyro 40,
GENEActiv 300 per page, counted from the start of each logging run; per-unit temperature is the
stored value (AX 10-bit code, GENEActiv 0.1 degC) at the unit's first sample. A halt or a restart
starts a new segment (and a restart resets the sequence id), as the readers do.
"""

from __future__ import annotations

from typing import Iterator

import numpy as np

from stillpoint.drivers import constants as C

from ..core.blocks import Block, DeviceInfo, QCEvent, QCReport
from .device import DeviceSim, make_devices


class SimSource:
    """A simulated device as a Source; arguments as ``make_devices`` for one device."""

    def __init__(self, *, device: str = "ax3", site: str = "wrist", days: float = 1.0,
                 hz: float = 100.0, effects=None, seed: int = 1, sim: DeviceSim = None, **kw):
        if sim is None:
            from .device import build_model
            [sim] = make_devices(sites=[site], devices=[device], days=days, hz=hz,
                                 effects=effects if effects is not None else build_model(None),
                                 seed=seed, **kw)
        self.sim = sim
        spec = sim.spec
        kind = {"ax3": "AX3", "ax6": "AX6", "geneactiv": "GENEActiv", "gt3x": "ActiGraph"}[spec.kind]
        gyro = spec.gyro_range_dps if spec.kind == "ax6" else None
        self.spu = 300 if spec.kind == "geneactiv" else (
            40 if gyro else (120 if spec.packed else 80))
        chans = ("accel_x", "accel_y", "accel_z") + (("gyro_x", "gyro_y", "gyro_z") if gyro else ())
        self.info = DeviceInfo(device_type=kind, device_id=str(sim.device_id), session_id=1,
                               firmware="sim", sample_rate_nominal=sim.hz,
                               accel_range_g=float(spec.range_g), gyro_range_dps=gyro,
                               channels=chans, metadata={"Body Location": sim.site},
                               header={"simulated": True, "seed": sim.seed})
        self.qc = QCReport(unit="page" if spec.kind == "geneactiv" else "sector")
        self._closed = False

    def close(self) -> None:
        self._closed = True

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def __iter__(self) -> Iterator[Block]:
        sim, spec, spu = self.sim, self.sim.spec, self.spu
        cpg = spec.counts_per_g
        zero = (np.asarray(spec.offsets, np.float64) / 100.0 if spec.kind == "geneactiv" else np.zeros(3))
        gdpc = spec.gyro_range_dps / 32768.0 if spec.gyro_range_dps and spec.kind == "ax6" else None
        segment, in_run, unit_index, seq, first = 0, 0, 0, 0, 0
        prev_t = None
        gap = 1.5 / sim.clock.rate_true_hz
        for c in sim.chunks():
            # split points: restarts and halts (a gap in true time) start a new segment
            cuts = set(c.restarts)
            d = np.diff(c.true_s)
            cuts.update((np.nonzero(d > gap)[0] + 1).tolist())
            if prev_t is not None and c.true_s[0] - prev_t > gap:
                cuts.add(0)
            edges = sorted(cuts | {0, c.n})
            for a, b in zip(edges[:-1], edges[1:]):
                if b <= a:
                    continue
                new_seg = a in cuts and (a > 0 or prev_t is not None)
                if new_seg:
                    segment += 1
                    restart = a in c.restarts
                    self.qc.add(QCEvent(unit_index, "restart" if restart else "time_jump",
                                        "simulated logging restart" if restart else "simulated sampling halt",
                                        time_ns=int(c.time_ns[a])))
                    in_run = 0
                    if restart:
                        seq = 0
                n = b - a
                # unit boundaries continue the current unit phase inside the run
                pos = (-in_run) % spu
                starts = np.arange(pos, n, spu)
                if pos > 0:
                    starts = np.concatenate([[0], starts])
                m = starts.shape[0]
                new_units = m - (1 if pos > 0 else 0)
                T = c.temperature_c[a:b][starts]
                if spec.kind == "geneactiv":
                    Tc = np.round(T, 1)
                    traw = np.full(m, -1, np.int32)
                else:
                    traw = np.clip(np.rint((T + 50.0) * (256.0 / 75.0)), 0, 1023).astype(np.int32)
                    Tc = C.cwa_temperature_c(traw)
                ui = unit_index - (1 if pos > 0 else 0) + np.arange(m)
                blk = Block(
                    time_ns=c.time_ns[a:b], accel=c.counts[a:b].astype(np.int16),
                    accel_counts_per_g=np.asarray(cpg, np.float64), accel_zero=zero,
                    gyro=None if c.gyro_counts is None else c.gyro_counts[a:b],
                    gyro_dps_per_count=gdpc, unit_index=ui.astype(np.int64),
                    unit_sequence=(seq - (1 if pos > 0 else 0) + np.arange(m)).astype(np.int64),
                    unit_start=starts.astype(np.int64), temperature_c=Tc.astype(np.float64),
                    temperature_raw=traw, light=np.zeros(m, np.int32), battery_v=np.full(m, np.nan),
                    events=np.zeros(m, np.uint8), segment=segment, first_sample=first)
                unit_index += new_units
                seq += new_units
                in_run += n
                first += n
                self.qc.total += new_units
                self.qc.valid += new_units
                yield blk
            prev_t = c.true_s[-1]
        self.qc.segments = segment + 1
