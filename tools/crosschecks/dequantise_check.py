"""How much of the quantisation pull the calibration's de-biasing removes, on drawn windows.

    python tools/crosschecks/dequantise_check.py [--windows 3000] [--step-mg 15.625]

For each noise SD: windows of 1000 readings of a known value, rounded to the step (AX3 packed
+-8 g: 15.625 mg) and averaged; prints the SD and the largest |window mean - value| before and
after engine.calibration.quantisation.dequantise_means, beside the noise of a window mean.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from stillpoint.engine.calibration.quantisation import dequantise_means


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--windows", type=int, default=3000)
    ap.add_argument("--step-mg", type=float, default=15.625)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args(argv)
    rng = np.random.default_rng(a.seed)
    q, n = a.step_mg / 1000.0, 1000
    for sig in (0.001, 0.0025, 0.0039, 0.006, 0.010):
        x = rng.uniform(-1, 1, (a.windows, 3))
        s = np.rint((x[:, None, :] + rng.normal(0, sig, (a.windows, n, 3))) / q) * q
        m, sd = s.mean(axis=1), s.std(axis=1, ddof=1)
        t = time.perf_counter()
        d = dequantise_means(m, sd, q)
        el = time.perf_counter() - t
        raw, fixed = (m - x) * 1000, (d - x) * 1000
        print(f"noise {sig * 1000:4.1f} mg: window mean - value SD {raw.std():.3f} mg (max "
              f"{np.abs(raw).max():.2f}) -> {fixed.std():.3f} mg (max {np.abs(fixed).max():.2f}); "
              f"noise of a mean {sig / np.sqrt(n) * 1000:.3f} mg; {el:.2f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
