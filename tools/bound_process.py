"""The vectorised same-work bound of `stillpoint process --mode batch`: what the same work costs
when written as straight numpy over each decoded block, without the engine's machinery.

    python tools/bound_process.py REC.cwa [--no-filter] [--no-zstd] [--zstd-level 1]

The work, as process does it:

1. decode the file (the drivers' reader) and compute 10 s window features (mean and SD per axis,
   mean temperature, mean norm) with ``reduceat`` over each block; a fixed affine correction
   stands in for the fit (the fit is ~1 % of a run);
2. decode the file again; per sample: temperature held per sector, affine correction with the
   temperature term, quantisation to 2^-16 g and float32, ENMO, the 4th-order Butterworth
   band-pass (BFEN, ``scipy.signal.sosfilt`` with its state carried across blocks), 5 s epoch
   means of ENMO/BFEN/x/y/z/temperature; zstd (level 1) of the raw counts plus the float32
   corrected stream in 10 s pieces (the log's chunk cadence) and of the epoch rows.

What it leaves out (so it is a lower bound on the same work): window and epoch cuts at segment
edges and across blocks (windows straddling a block edge are simply cut), the MCAP framing and
indexes, the per-message headers, the estimate, QC and metadata records, the nonmovement
selection and the batch schedule. ``--no-filter`` / ``--no-zstd`` drop the band-pass / the
compression, for the stage costs. It prints the samples and the compressed bytes; run it under
tools/bench_process.py (``measure``) for CPU, wall and peak RSS.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

WINDOW_NS = 10 * 10**9
EPOCH_NS = 5 * 10**9
PIECE_NS = 10 * 10**9  # the log's default flush cadence


def _window_features(t, g, temp):
    w = (t - t[0]) // WINDOW_NS
    st = np.concatenate([[0], np.flatnonzero(w[1:] != w[:-1]) + 1])
    cnt = np.diff(np.append(st, t.shape[0]))
    out = []
    for j in range(3):
        c = g[:, j]
        s1 = np.add.reduceat(c, st)
        s2 = np.add.reduceat(c * c, st)
        out.append(s1 / cnt)
        out.append(np.sqrt(np.maximum(s2 - s1 * s1 / cnt, 0) / np.maximum(cnt - 1, 1)))
    out.append(np.add.reduceat(temp, st) / cnt)
    norm = np.sqrt(g[:, 0] ** 2 + g[:, 1] ** 2 + g[:, 2] ** 2)
    out.append(np.add.reduceat(norm, st) / cnt)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("path")
    ap.add_argument("--no-filter", action="store_true")
    ap.add_argument("--no-zstd", action="store_true")
    ap.add_argument("--zstd-level", type=int, default=1)
    a = ap.parse_args(argv)
    from stillpoint.drivers import open_recording
    from stillpoint.engine.operators.filters import bandpass_sos

    # pass 1: decode + window features
    windows = 0
    with open_recording(a.path) as src:
        rate = float(src.info.sample_rate_nominal)
        for b in src:
            g = b.accel.astype(np.float64) / b.accel_counts_per_g
            windows += len(_window_features(b.time_ns, g, b.temperature_per_sample())[0])
    offset, scale, tempoffset, tref = (np.array([0.01, -0.02, 0.03]), np.array([1.01, 0.99, 1.0]),
                                       np.array([1e-3, -5e-4, 2e-4]), 25.0)
    # pass 2: decode + correction + metrics + compression
    sos = bandpass_sos(rate)
    zi = np.zeros((sos.shape[0], 3, 2))
    comp = None
    if not a.no_zstd:
        import zstandard
        comp = zstandard.ZstdCompressor(level=a.zstd_level).compress
    n = nbytes = epochs = 0
    from scipy.signal import sosfilt
    with open_recording(a.path) as src:
        for b in src:
            t = b.time_ns
            temp = b.temperature_per_sample()
            g = b.accel.astype(np.float64) / b.accel_counts_per_g
            cal = (g + offset) * scale + (temp - tref)[:, None] * tempoffset
            q = (np.round(cal * 65536.0) / 65536.0).astype(np.float32)
            r = np.sqrt(np.einsum("ij,ij->i", cal, cal))
            enmo = np.maximum(r - 1.0, 0.0)
            if a.no_filter:
                bfen = r
            else:
                f, zi = sosfilt(sos, np.ascontiguousarray(cal.T), axis=-1, zi=zi)  # (3, n)
                bfen = np.sqrt(np.einsum("ij,ij->j", f, f))
            e = t // EPOCH_NS
            st = np.concatenate([[0], np.flatnonzero(e[1:] != e[:-1]) + 1])
            cnt = np.diff(np.append(st, t.shape[0]))
            rows = np.column_stack([np.add.reduceat(x, st) / cnt for x in
                                    (enmo, bfen, cal[:, 0], cal[:, 1], cal[:, 2], temp)])
            epochs += rows.shape[0]
            if comp is not None:
                p = (t - t[0]) // PIECE_NS
                cuts = np.concatenate([[0], np.flatnonzero(p[1:] != p[:-1]) + 1, [t.shape[0]]])
                raw = b.accel
                for i, j in zip(cuts[:-1], cuts[1:]):
                    nbytes += len(comp(raw[i:j].tobytes() + q[i:j].tobytes()))
                nbytes += len(comp(rows.tobytes()))
            n += b.n
    print(f"{n} samples, {windows} windows, {epochs} epochs, {nbytes} compressed bytes")
    return 0


if __name__ == "__main__":
    sys.exit(main())
