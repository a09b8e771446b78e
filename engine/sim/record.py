"""Streaming generation of simulated recordings: one or two devices on one body, written as real
.cwa/.bin/.gt3x files through the project's writers, plus the ground truth (JSON + per-10 s-window
label CSV).

API
---
``simulate_recording(path, device="ax3", site="wrist", days=7, hz=100, effects=None, seed=1,
truth_path=None, ...) -> Truth`` writes one file (+ truth) and returns the truth.
``simulate_pair(path_a, path_b, site_a="wrist", site_b="hip", ...) -> (Truth, Truth)``: two
devices driven by the same movement (same step times), each with its own sensor errors and clock.
``DeviceSim`` / ``make_devices(...)``: the in-memory generator; ``DeviceSim.chunks()`` yields
``SimChunk``s (true time, device time, true and measured acceleration, counts) without a file.

Determinism: the body schedule, every per-segment orientation, the slow tracks (temperature,
clock, bias) and the sensor's parameters come from the seed; the white noise of chunk k (one hour
of true time) comes from SeedSequence((seed, 3, device index, k)). Same seed -> same bytes.
Memory: one hour of samples per device at a time (100 Hz: 360k samples, ~60 MB of temporaries),
plus the slow tracks (one value per 10 s); labels are streamed to the CSV chunk by chunk.

The device model lives in ``device`` and the truth/label formats in ``truth``; their public
names are re-exported here.
"""

from __future__ import annotations

from pathlib import Path
from typing import Iterator, Optional

import numpy as np

from stillpoint.engine.core.malloc import tune_for_blocks

from .device import (DEFAULT_START, DeviceSim, SimChunk, build_model,  # noqa: F401
                     make_devices, _device_hz)
from .model import ModelError, SensorModel  # noqa: F401
from .temperature import TRACK_STEP_S, TemperatureParams
from .truth import (LABEL_COLUMNS, TRUTH_FORMAT, WINDOW_S, Truth, _write_label_rows,  # noqa: F401
                    load_labels, load_truth, relative_clock_s, truth_device_time, write_labels)
from .wearer import ACTIVITIES, WearerParams, nonwear_summary


# ----------------------------------------------------------------------------- writing
class _FileSink:
    """A device's writer plus the label accumulators.

    Every output (recording, labels CSV, truth JSON) is written as ``<name>.part``
    (``stillpoint.engine.core.outputs``) and renamed only by ``commit()``, once all of them are
    complete, the recording last: a run that fails (full disk, kill) leaves no file that looks
    complete. ``abandon()`` stops and keeps the partial files aside."""

    def __init__(self, sim: DeviceSim, path, *, labels_path=None, truth_path=None,
                 session_id: int = 1):
        self.sim = sim
        self.path = Path(path)
        self.labels_path = Path(labels_path) if labels_path else None
        self.truth_path = Path(truth_path) if truth_path else None
        self._outs = []  # AtomicOutputs in commit order: labels, truth, recording
        try:
            if self.labels_path is not None:
                self._labels_out = self._open(self.labels_path, binary=False, what="labels")
            self._truth_out = (self._open(self.truth_path, binary=False, what="truth")
                               if self.truth_path is not None else None)
            self._rec_out = self._open(self.path, binary=True, what="recording")
        except BaseException:
            self.abandon()
            raise
        # a .gz output is written plain first (corrupt sectors are applied to the plain file),
        # then compressed into the locked partial file on close
        self.gz = self.path.name.endswith(".gz")
        self.plain = (self.path.with_name(self.path.name[:-3] + ".plain.part") if self.gz
                      else self._rec_out.part)
        spec = sim.spec
        if spec.kind in ("ax3", "ax6"):
            from stillpoint.drivers.cwa import CwaWriter
            self.writer = CwaWriter(self.plain, device_type=spec.kind.upper(), device_id=sim.device_id,
                                    session_id=session_id, rate_hz=sim.hz, range_g=spec.range_g,
                                    packed=spec.packed if spec.kind == "ax3" else False,
                                    gyro_range_dps=spec.gyro_range_dps,
                                    metadata={"_p": sim.site, "_sc": f"sim-seed-{sim.seed}"})
        elif spec.kind == "gt3x":
            from stillpoint.drivers.gt3x_writer import Gt3xWriter
            if self.gz:
                raise ValueError(f"{self.path}: a .gt3x is a zip already; write it without .gz")
            self.writer = Gt3xWriter(self.plain, serial=f"MOS2E{sim.device_id:08d}", rate_hz=sim.hz,
                                     scale=float(spec.counts_per_g[0]), subject=f"sim-seed-{sim.seed}",
                                     idle_sleep=spec.idle_sleep)
        else:
            from stillpoint.drivers.geneactiv import GeneactivWriter
            self.writer = GeneactivWriter(self.plain, serial=f"{sim.device_id:06d}", rate_hz=sim.hz,
                                          gains=spec.gains, offsets=spec.offsets,
                                          header_fields={"Device Location Code": sim.site})
        # labels are streamed: a chunk (1 h) holds whole windows (10 s), so the windows up to a
        # chunk's end are final once it is pushed; memory stays flat in the recording length
        self.nw = int(np.ceil(sim.duration_s / WINDOW_S))
        self.next_window = 0
        self._labels_f = None
        self._in_memory = [] if self.labels_path is None else None
        if self.labels_path is not None:
            self._labels_f = self._labels_out.file
            self._labels_f.write(",".join(LABEL_COLUMNS) + "\n")
        self.stats = {"still": 0, "windows": 0, "activity": np.zeros(len(ACTIVITIES), np.int64),
                      "worn_T": []}
        self.samples = 0
        self._battery_grid = None

    def _emit(self, labels: dict) -> None:
        st = self.stats
        st["still"] += int(labels["still"].sum())
        st["windows"] += labels["still"].shape[0]
        st["activity"] += np.bincount(labels["activity"], minlength=len(ACTIVITIES))
        st["worn_T"].append(labels["temperature_c"][labels["activity"] > 1].astype(np.float32))
        if self._labels_f is not None:
            _write_label_rows(self._labels_f, labels)
        else:
            self._in_memory.append(labels)

    def _emit_until(self, w_end: int, sums=None, sq=None, counts=None) -> None:
        """Emit windows next_window .. w_end - 1 (zeros where no sample fell)."""
        n = w_end - self.next_window
        if n <= 0:
            return
        if counts is None:
            sums, sq, counts = np.zeros((n, 3)), np.zeros((n, 3)), np.zeros(n, np.int64)
        self._emit(self.sim.labels(sums, sq, counts, first_window=self.next_window))
        self.next_window = w_end

    def push(self, c: SimChunk) -> None:
        nw = self.nw
        w0 = min(int(c.true_s[0] // WINDOW_S), nw - 1)
        w1 = min(int(c.true_s[-1] // WINDOW_S), nw - 1)
        self._emit_until(w0)  # windows without samples (halt / restart gaps) before this chunk
        w0 = self.next_window
        edges = np.searchsorted(c.true_s, np.arange(w0, w1 + 1) * WINDOW_S, side="left")
        edges[0] = 0
        nz = np.diff(np.append(edges, c.n)) > 0  # windows with samples in this chunk
        starts = edges[nz]
        wins = np.arange(w0, w1 + 1)[nz] - w0
        k = w1 + 1 - w0
        counts = np.zeros(k, np.int64)
        sums, sq = np.zeros((k, 3)), np.zeros((k, 3))
        counts[wins] = np.diff(np.append(starts, c.n))
        # per axis on a contiguous float64 copy: the same sums as reducing the (n, 3) array
        # along its rows (the same additions in the same order), several times faster
        g = np.empty(c.n)
        for j in range(3):
            g[:] = c.true_g[:, j]
            sums[wins, j] = np.add.reduceat(g, starts)
            g *= g
            sq[wins, j] = np.add.reduceat(g, starts)
        self._emit_until(w1 + 1, sums, sq, counts)
        cuts = [0] + list(c.restarts) + [c.n]
        for p, (a, b) in enumerate(zip(cuts[:-1], cuts[1:])):
            if p > 0 and hasattr(self.writer, "restart"):
                self.writer.restart()
            if b <= a:
                continue
            self._write(c, a, b)
        self.samples += c.n

    def _grid_values(self, t: np.ndarray, *grids: np.ndarray) -> list:
        """Values of slow channels on the 10 s grid at times t: ``grid[gi]`` with
        gi = min(int(t / TRACK_STEP_S), last); for increasing t as one value per grid cell
        repeated over the cell's samples (the same values as the per-sample gathers)."""
        last = self.sim.t_grid.shape[0] - 1
        x = t * (1.0 / TRACK_STEP_S)
        if t.shape[0] > 1 and not bool(np.all(x[1:] >= x[:-1])):
            gi = np.minimum(x.astype(np.int64), last)
            return [g[gi] for g in grids]
        lo, hi = min(int(x[0]), last), min(int(x[-1]), last)
        edges = np.searchsorted(x, np.arange(lo + 1, hi + 1), side="left")  # first sample of cells lo+1..hi
        counts = np.diff(np.concatenate([[0], edges, [t.shape[0]]]))
        return [np.repeat(g[lo:hi + 1], counts) for g in grids]

    def _write(self, c: SimChunk, a: int, b: int) -> None:
        sim = self.sim
        t = c.true_s[a:b]
        if self._battery_grid is None:  # the slow channels' grids are made once per recording
            self._light_grid, self._battery_grid = _aux_grids(sim)
        # slow channels from the 10 s grid (a sector keeps one value)
        light, battery = self._grid_values(t, self._light_grid, self._battery_grid)
        if sim.spec.kind == "gt3x":  # accelerometer only (no temperature in the format)
            self.writer.write(c.time_ns[a:b], c.counts[a:b])
        elif sim.spec.kind in ("ax3", "ax6"):
            traw = _ax_temperature_raw(c.temperature_c[a:b])
            self.writer.write(c.time_ns[a:b], c.counts[a:b],
                              gyro_counts=None if c.gyro_counts is None else c.gyro_counts[a:b],
                              temperature_raw=traw, light_raw=light, battery_raw=battery)
        else:
            self.writer.write(c.time_ns[a:b], c.counts[a:b], light_raw=light,
                              temperature_c=np.round(c.temperature_c[a:b], 1), battery_v=battery)

    def _open(self, path: Path, *, binary: bool, what: str):
        from stillpoint.engine.core.outputs import AtomicOutput
        out = AtomicOutput(path, binary=binary, what=what)
        self._outs.append(out)
        return out

    def close(self) -> list:
        """Finish writing (nothing is renamed yet: see ``commit``)."""
        self._emit_until(self.nw)
        if self._labels_f is not None:
            self._labels_f.flush()
        self.writer.close()
        corrupt = []
        m = self.sim.model
        if m.on("corrupt_sectors"):
            corrupt = self._corrupt(m.effects["corrupt_sectors"])
        if self.gz:
            import gzip
            import shutil
            # the name in the gzip header is the final one (same bytes as a direct write)
            with open(self.plain, "rb") as src, gzip.GzipFile(str(self.path), "wb", compresslevel=6,
                                                              mtime=0, fileobj=self._rec_out.file) as dst:
                shutil.copyfileobj(src, dst, 1 << 20)
            self.plain.unlink()
        return corrupt

    def write_truth(self, text: str) -> None:
        self._truth_out.file.write(text)

    def commit(self) -> None:
        """Rename every output into place, the recording last."""
        for out in self._outs:
            out.commit()

    def abandon(self) -> None:
        """Stop after a failure: the partial files stay (``*.part``), nothing looks complete."""
        try:
            w = getattr(self, "writer", None)
            if w is not None and getattr(w, "_f", None) is not None:
                w._f.close()
        except Exception:
            pass
        for out in self._outs:
            if not out.committed:
                out.abandon()
        if getattr(self, "gz", False) and self.plain.exists():
            try:
                self.plain.unlink()
            except OSError:
                pass

    def _corrupt(self, p: dict) -> list:
        if self.sim.spec.kind == "geneactiv":
            from .corrupt import corrupt_bin_pages
            n_units = _count_bin_pages(self.plain)
        else:
            n_units = (self.plain.stat().st_size - 1024) // 512
        if "indices" in p:
            idx = sorted(int(i) for i in p["indices"] if 0 <= int(i) < n_units)
        else:
            r = np.random.default_rng(np.random.SeedSequence([self.sim.seed, 7, self.sim.dev_index]))
            k = min(int(p.get("count", 3)), max(n_units - 2, 0))
            idx = sorted(int(i) for i in r.choice(np.arange(1, max(n_units - 1, 1)), k, replace=False)) if k else []
        if self.sim.spec.kind == "geneactiv":
            corrupt_bin_pages(self.plain, idx)
        else:
            from stillpoint.drivers.cwa import corrupt_sector
            for i in idx:
                corrupt_sector(self.plain, i, "checksum")
        return idx


def _aux_grids(sim: DeviceSim) -> tuple[np.ndarray, np.ndarray]:
    """The light and battery channels on the 10 s grid as the writer takes them: AX ADC values
    (light 0-1023, battery 1-255, as int16: a quarter of the bytes to repeat per sample), or
    GENEActiv light and battery volts."""
    bv = sim.battery_v(sim.t_grid)
    if sim.spec.kind in ("ax3", "ax6"):
        battery = np.clip(np.rint(bv * 1024.0 / 6.0 - 512.0), 1, 255).astype(np.int16)
        return np.clip(sim.light_grid, 0, 1023).astype(np.int16), battery
    return sim.light_grid, np.round(bv, 4)


def _ax_temperature_raw(temperature_c: np.ndarray) -> np.ndarray:
    """AX temperature ADC values (0-1023, int16) of temperatures in degC:
    rint((T + 50) * 256 / 75), clipped (rounded and clipped in the temperatures' dtype: the
    values are whole numbers there, so the same as clipping the integers)."""
    x = (temperature_c + 50.0) * (256.0 / 75.0)
    np.rint(x, out=x)
    np.clip(x, 0, 1023, out=x)
    return x.astype(np.int16)


def _count_bin_pages(path) -> int:
    n = 0
    with open(path, "rb") as f:
        for line in f:
            if line.startswith(b"Recorded Data"):
                n += 1
    return n


def _paths(path, truth_path, labels_path):
    """(truth path, labels path), or (None, None) for truth_path=False."""
    if truth_path is False:
        return None, None
    tp = Path(truth_path) if truth_path else _default_truth_path(Path(path))
    if labels_path:
        return tp, Path(labels_path)
    stem = tp.name[: -len(".truth.json")] if tp.name.endswith(".truth.json") else tp.stem
    return tp, tp.with_name(stem + ".labels.csv")


def _finish(sim: DeviceSim, sink: _FileSink, corrupt: list, truth_path: Optional[Path], pair=None) -> Truth:
    st = sink.stats
    worn_T = np.concatenate(st["worn_T"]) if st["worn_T"] else np.zeros(0)
    summary = {
        "still_window_fraction": float(st["still"] / max(st["windows"], 1)),
        "still_hours_per_day": float(st["still"] * WINDOW_S / 3600.0 / max(sim.duration_s / 86400.0, 1e-9)),
        "worn_temperature_c_p5_p95": ([float(np.percentile(worn_T, 5)), float(np.percentile(worn_T, 95))]
                                      if worn_T.size else None),
        "activity_hours": {a: float(st["activity"][i] * WINDOW_S / 3600.0) for i, a in enumerate(ACTIVITIES)},
        "steps": int(np.count_nonzero((sim.schedule.steps >= 0) & (sim.schedule.steps < sim.duration_s))),
        "nonwear": nonwear_summary(sim.schedule),
    }
    truth = Truth(path=str(sink.path), device=dict(sim.spec.to_dict(), device_id=sim.device_id),
                  site=sim.site, seed=sim.seed, start_ns=sim.start_ns, duration_s=sim.duration_s,
                  rate_hz_nominal=sim.hz, rate_hz_true=sim.clock.rate_true_hz,
                  sensor_model=sim.model, clock=sim.clock_truth(),
                  wearer=sim.schedule.params.to_dict(), temperature=sim.tparams.to_dict(),
                  samples_written=sink.samples, corrupt_sectors=corrupt, summary=summary, pair=pair)
    if truth_path is not None:
        truth.labels_path = str(sink.labels_path)
        truth.truth_path = str(truth_path)
        sink.write_truth(truth.to_json_text())
    else:
        parts = sink._in_memory
        truth._labels = {k: np.concatenate([p[k] for p in parts]) for k in LABEL_COLUMNS} if parts else None
    return truth


def _default_truth_path(path: Path) -> Path:
    name = path.name
    for suf in (".cwa.gz", ".bin.gz", ".cwa", ".bin", ".gt3x"):
        if name.endswith(suf):
            return path.with_name(name[: -len(suf)] + ".truth.json")
    return path.with_name(name + ".truth.json")


def iter_chunks(*, device: str = "ax3", site: str = "wrist", days: float = 1.0, hz: float = 100.0,
                effects=None, seed: int = 1, **kw) -> Iterator[SimChunk]:
    """In-memory generator (no file): the chunks of one simulated device. The DeviceSim (with
    the resolved model, clock and tracks) is ``make_devices(...)[0]`` with the same arguments."""
    [sim] = make_devices(sites=[site], devices=[device], days=days, hz=hz, effects=effects,
                         seed=seed, **kw)
    return sim.chunks()


def simulate_recording(path, *, device: str = "ax3", site: str = "wrist", days: float = 7.0,
                       hz: float = 100.0, effects=None, seed: int = 1, truth_path=None,
                       labels_path=None, start=None, range_g=None, packed=None,
                       gyro_range_dps=None, wearer: Optional[WearerParams] = None,
                       temperature: Optional[TemperatureParams] = None,
                       device_id: Optional[int] = None, session_id: int = 1,
                       progress=None) -> Truth:
    """Simulate one device and write it to ``path`` (.cwa for ax3/ax6, .bin for geneactiv) plus
    the truth JSON (default: beside the file, ``<name>.truth.json``; ``truth_path=False``: none)
    and the per-window labels CSV (``<name>.labels.csv``). ``device_id`` (default: drawn from
    the seed) and ``session_id`` go into the file's header and sectors. ``progress(fraction)`` is
    called after each chunk (an ``engine.progress.Progress``'s ``update``, or None)."""
    [sim] = make_devices(sites=[site], devices=[device], days=days, hz=hz, effects=effects, seed=seed,
                         start=start, range_g=range_g, packed=packed, gyro_range_dps=gyro_range_dps,
                         wearer=wearer, temperature=temperature)
    if device_id is not None:
        sim.device_id = int(device_id)
    tp, lp = _paths(path, truth_path, labels_path)
    sink = _FileSink(sim, path, labels_path=lp, truth_path=tp, session_id=session_id)
    try:
        for k, c in enumerate(sim.chunks()):
            sink.push(c)
            if progress is not None:
                progress(fraction=(k + 1) / max(sim.n_chunks, 1))
        corrupt = sink.close()
        truth = _finish(sim, sink, corrupt, tp)
        sink.commit()
    except BaseException as e:
        sink.abandon()
        _reraise(e, [sink])
    return truth


def device_recording(path, *, device: str, days: float, hz: float, seed: int, device_id: int,
                     session_id: int, gyro_range_dps: Optional[float], packed: Optional[bool]) -> None:
    """The recording an emulated AX3/AX6 holds (``drivers/ax/emulator.py``'s ``make_recording``):
    the simulator's default wearer and device effects, no truth or label files."""
    simulate_recording(path, device=device, days=days, hz=hz, seed=seed, truth_path=False,
                       device_id=device_id, session_id=session_id, effects="default",
                       gyro_range_dps=gyro_range_dps, packed=packed)


def _reraise(e: BaseException, sinks) -> None:
    """An OS error while writing (full disk, folder removed) becomes an ``OutputError`` naming
    the output; every other exception propagates unchanged."""
    from stillpoint.engine.core.errors import StillpointError
    from stillpoint.engine.core.outputs import OutputError, describe_os_error
    if isinstance(e, OSError) and not isinstance(e, StillpointError):
        names = ", ".join(str(s.path) for s in sinks)
        raise OutputError(names, f"{describe_os_error(e)}; nothing was completed (partial files "
                                 "end in .part)") from None
    raise e


def simulate_pair(path_a, path_b, *, site_a: str = "wrist", site_b: str = "hip",
                  device_a: str = "ax3", device_b: Optional[str] = None, days: float = 7.0,
                  hz: float = 100.0, hz_b: Optional[float] = None, effects=None, effects_b=None,
                  seed: int = 1, truth_a=None, truth_b=None, start=None, range_g=None,
                  packed=None, gyro_range_dps=None, wearer: Optional[WearerParams] = None,
                  temperature: Optional[TemperatureParams] = None,
                  progress=None) -> tuple[Truth, Truth]:
    """Two devices on one body (same movement and step times; own orientation, dynamics,
    sensor errors and clock each). Written chunk by chunk in lockstep; ``progress(fraction)``
    as in ``simulate_recording``."""
    device_b = device_b or device_a
    m_a = build_model(effects)
    m_b = build_model(effects_b) if effects_b is not None else build_model(effects)
    sims = make_devices(sites=[site_a, site_b], devices=[device_a, device_b], days=days, hz=hz,
                        seed=seed, start=start, range_g=range_g, packed=packed,
                        gyro_range_dps=gyro_range_dps, wearer=wearer, temperature=temperature,
                        models=[m_a, m_b])
    if hz_b is not None and hz_b != hz:
        b = sims[1]
        sims[1] = DeviceSim(b.schedule, site=b.site, spec=b.spec, model=m_b, seed=seed, dev_index=1,
                            hz=_device_hz(b.spec.kind, hz_b), duration_s=b.duration_s, start_ns=b.start_ns,
                            temperature=temperature, device_id=b.device_id)
    paths = [_paths(path_a, truth_a, None), _paths(path_b, truth_b, None)]
    sinks = [_FileSink(sims[0], path_a, labels_path=paths[0][1], truth_path=paths[0][0])]
    try:
        sinks.append(_FileSink(sims[1], path_b, labels_path=paths[1][1], truth_path=paths[1][0]))
        tune_for_blocks()
        n_chunks = max(s.n_chunks for s in sims)
        for k in range(n_chunks):
            for s, sink in zip(sims, sinks):
                c = s.chunk(k) if k < s.n_chunks else None
                if c is not None and c.n:
                    sink.push(c)
            if progress is not None:
                progress(fraction=(k + 1) / max(n_chunks, 1))
        corrupt = [sink.close() for sink in sinks]
        pair = {"sites": [site_a, site_b], "paths": [str(path_a), str(path_b)]}
        ta = _finish(sims[0], sinks[0], corrupt[0], paths[0][0], dict(pair, this=0))
        tb = _finish(sims[1], sinks[1], corrupt[1], paths[1][0], dict(pair, this=1))
        for sink in sinks:
            sink.commit()
    except BaseException as e:
        for sink in sinks:
            sink.abandon()
        _reraise(e, sinks)
    return ta, tb
