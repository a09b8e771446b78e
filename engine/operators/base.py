"""What the pipeline's operators share: ring sizes (``ring_capacity``) and the column-wise
(n, 3) maths. The protocol every operator follows (``push``/``flush``, outputs independent of
how the input was cut) is ``Operator`` in engine/core/pipeline.py.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import numpy as np


def ring_capacity(width_s: float, rate_hz: float, minimum: int = 4096) -> int:
    """Samples a ring must hold for one bin of ``width_s`` at ``rate_hz`` (with 2x headroom)."""
    return max(minimum, int(2 * width_s * max(rate_hz, 1.0)) + 1024)


# ---------------------------------------------------------------------------- (n, 3) maths
# numpy broadcasts an (n, 3) array against a (3,) vector with an inner loop of length 3, much
# slower than three strided column loops (docs/performance.md#code-figures); these helpers do the same element-wise operations, in
# the same order, column by column (results are bit-identical to the broadcast forms) into a
# (3, n) array whose transpose, an (n, 3) view, is returned.


def accel_g_columns(block, out_t=None) -> np.ndarray:
    """``block.accel_g()`` (float64 g, (n, 3)), computed column by column; ``out_t``: a (3, n)
    array to write into (rows contiguous, e.g. the tail of a larger buffer)."""
    import numpy as np
    acc = block.accel
    out = np.empty((3, acc.shape[0])) if out_t is None else out_t
    zero = block.accel_zero.astype(np.float64)
    cpg = block.accel_counts_per_g.astype(np.float64)
    shift = bool(np.any(block.accel_zero))
    for j in range(3):
        c = out[j]
        c[...] = acc[:, j]
        if shift:
            c -= zero[j]
        c /= cpg[j]
    return out.T


def apply_columns(est, accel, temperature, out_t=None) -> np.ndarray:
    """``est.apply(accel, temperature)`` ((x + offset) * scale [+ (T - ref) * tempoffset]),
    column by column; ``out_t``: a (3, n) array to write into. Returns the (n, 3) view."""
    import numpy as np
    n = accel.shape[0]
    out = np.empty((3, n)) if out_t is None else out_t
    dt = term = None
    if est.uses_temperature:
        if temperature is None:
            raise ValueError("this estimate has a temperature term; temperature is required")
        dt = np.subtract(np.asarray(temperature, np.float64), est.temperature_ref)
        term = np.empty(n)  # one scratch column for dt * tempoffset
    for j in range(3):
        c = out[j]
        np.add(accel[:, j], est.offset[j], out=c)
        c *= est.scale[j]
        if dt is not None:
            c += np.multiply(dt, est.tempoffset[j], out=term)
    return out.T
