"""The vectorised same-work bound of `stillpoint process --mode batch`: what the same work costs
when written as straight numpy over each decoded block, without the engine's machinery.

    python tools/benchmarks/bound_process.py REC.cwa [--no-filter] [--no-zstd] [--zstd-level 1]

tools/benchmarks/bench_process.py runs it on the realistic ``stillpoint simulate`` file first (default
wearer) and on the window-feature test pattern second, beside ``process`` in the same run.

The work, as process does it, in the fastest plain numpy forms (three contiguous rows instead of
(n, 3)-by-(3,) broadcasts, exact integer sums for the window features):

1. decode the file (the drivers' reader) and compute 10 s window features (mean and SD per axis,
   mean temperature, mean norm) with ``reduceat`` over each block; a fixed affine correction
   stands in for the fit (the fit is ~1 % of a run);
2. decode the file again; per sample: temperature held per sector, affine correction with the
   temperature term, quantisation to 2^-16 g and float32, ENMO, the 4th-order Butterworth
   band-pass (BFEN: scipy's compiled sosfilt kernel, state carried across blocks), 5 s epoch
   means of ENMO/BFEN/x/y/z/temperature; zstd (level 1) of the raw counts plus the float32
   corrected stream in 10 s pieces (the log's chunk cadence) and of the epoch rows.

What it leaves out (so it is a lower bound on the same work): window and epoch cuts at segment
edges and across blocks (windows straddling a block edge are simply cut), the MCAP framing and
indexes, the per-message headers, the estimate, QC and metadata records, the nonmovement
selection and the batch schedule. ``--no-filter`` / ``--no-zstd`` drop the band-pass / the
compression, for the stage costs. It prints the samples and the compressed bytes; run it under
tools/benchmarks/bench_process.py (``measure``) for CPU, wall and peak RSS.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

WINDOW_NS = 10 * 10**9
EPOCH_NS = 5 * 10**9
PIECE_NS = 10 * 10**9  # the log's default flush cadence


def _columns(acc, dtype=np.float64):
    """(3, n) float copy of the (n, 3) counts (column by column: numpy's (n, 3)-by-(3,)
    broadcasts are several times slower than three contiguous rows)."""
    out = np.empty((3, acc.shape[0]), dtype)
    for j in range(3):
        out[j] = acc[:, j]
    return out


def _window_features(t, c, cpg, temp):
    """Mean and SD per axis (exact sums of counts), mean temperature and mean norm per 10 s."""
    w = (t - t[0]) // WINDOW_NS
    st = np.concatenate([[0], np.flatnonzero(w[1:] != w[:-1]) + 1])
    cnt = np.diff(np.append(st, t.shape[0]))
    out = []
    sq = c * c
    for j in range(3):
        s1 = np.add.reduceat(c[j], st)
        s2 = np.add.reduceat(sq[j], st)
        out.append(s1 / cnt / cpg)
        out.append(np.sqrt((cnt * s2 - s1 * s1) / (cnt * np.maximum(cnt - 1, 1))) / cpg)
    out.append(np.add.reduceat(temp, st) / cnt)
    out.append(np.add.reduceat(np.sqrt(sq[0] + sq[1] + sq[2]), st) / cnt / cpg)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("path")
    ap.add_argument("--no-filter", action="store_true")
    ap.add_argument("--no-zstd", action="store_true")
    ap.add_argument("--zstd-level", type=int, default=1)
    a = ap.parse_args(argv)
    from stillpoint.drivers import open_recording
    from stillpoint.engine.operators.filters import SosStream, bandpass_sos

    # pass 1: decode + window features
    windows = 0
    with open_recording(a.path) as src:
        rate = float(src.info.sample_rate_nominal)
        for b in src:
            windows += len(_window_features(b.time_ns, _columns(b.accel), b.accel_counts_per_g[0],
                                            b.temperature_per_sample())[0])
    offset, scale, tempoffset, tref = (np.array([0.01, -0.02, 0.03]), np.array([1.01, 0.99, 1.0]),
                                       np.array([1e-3, -5e-4, 2e-4]), 25.0)
    # pass 2: decode + correction + metrics + compression
    filt = SosStream(bandpass_sos(rate), 3)  # scipy's compiled sosfilt kernel, state carried
    comp = None
    if not a.no_zstd:
        import zstandard
        comp = zstandard.ZstdCompressor(level=a.zstd_level).compress
    n = nbytes = epochs = 0
    with open_recording(a.path) as src:
        for b in src:
            t = b.time_ns
            dT = b.temperature_per_sample() - tref
            cal = _columns(b.accel)  # (3, n)
            q = np.empty(cal.shape, np.float32)
            r2 = np.zeros(t.shape[0])
            for j in range(3):
                c = cal[j]
                c /= b.accel_counts_per_g[j]
                c += offset[j]
                c *= scale[j]
                c += dT * tempoffset[j]
                r2 += c * c
                q[j] = np.rint(c * 65536.0) / 65536.0
            r = np.sqrt(r2)
            enmo = np.maximum(r - 1.0, 0.0)
            if a.no_filter:
                bfen = r
            else:
                f = filt.push(cal.T)  # (n, 3) view of a filtered (3, n) copy
                bfen = np.sqrt(f[:, 0] ** 2 + f[:, 1] ** 2 + f[:, 2] ** 2)
            e = t // EPOCH_NS
            st = np.concatenate([[0], np.flatnonzero(e[1:] != e[:-1]) + 1])
            cnt = np.diff(np.append(st, t.shape[0]))
            rows = np.stack([np.add.reduceat(x, st) / cnt for x in
                             (enmo, bfen, cal[0], cal[1], cal[2], dT)])
            epochs += rows.shape[1]
            if comp is not None:
                p = (t - t[0]) // PIECE_NS
                cuts = np.concatenate([[0], np.flatnonzero(p[1:] != p[:-1]) + 1, [t.shape[0]]])
                raw = b.accel
                for i, j in zip(cuts[:-1], cuts[1:]):
                    nbytes += len(comp(raw[i:j].tobytes() + q[:, i:j].tobytes()))
                nbytes += len(comp(rows.tobytes()))
            n += b.n
    print(f"{n} samples, {windows} windows, {epochs} epochs, {nbytes} compressed bytes")
    return 0


if __name__ == "__main__":
    sys.exit(main())
