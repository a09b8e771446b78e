"""Fixed-capacity ring buffer of per-sample columns addressed by absolute sample index.

The ring buffer is how an operator sees a window that spans two (or more) blocks: the samples of
the not-yet-complete window stay in the ring until the block that completes it arrives. Its
capacity is the memory bound of the operator; appending beyond it raises ``BufferError`` (never
grows silently).

Columns share one index: ``RingBuffer(capacity, time=(np.int64, ()), accel=(np.float64, (3,)))``.
``start`` is the absolute index of the oldest retained sample, ``end`` one past the newest.
``view(a, b)`` returns the columns of samples ``[a, b)``: numpy views when the range does not wrap
around the end of the storage, copies otherwise.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np


class RingBuffer:
    """A fixed-capacity buffer of equal-length numpy columns (see the module docstring)."""
    def __init__(self, capacity: int, **columns):
        if capacity <= 0:
            raise ValueError("capacity must be positive")
        if not columns:
            raise ValueError("a ring buffer needs at least one column")
        self.capacity = int(capacity)
        self._data = {name: np.empty((self.capacity,) + tuple(shape), dtype)
                      for name, (dtype, shape) in columns.items()}
        self.start = 0  # absolute index of the oldest sample held
        self.end = 0  # absolute index one past the newest sample held

    # ------------------------------------------------------------------ state
    def __len__(self) -> int:
        return self.end - self.start

    @property
    def free(self) -> int:
        """Rows that can still be appended."""
        return self.capacity - len(self)

    @property
    def nbytes(self) -> int:
        """Bytes held by the columns."""
        return sum(a.nbytes for a in self._data.values())

    def clear(self) -> None:
        """Drop everything; the absolute index continues from ``end``."""
        self.start = self.end

    # ------------------------------------------------------------------ write
    def append(self, **values) -> None:
        """Append equal-length arrays, one per column (all columns required)."""
        if set(values) != set(self._data):
            raise KeyError(f"append needs exactly the columns {sorted(self._data)}")
        n = None
        for v in values.values():
            if n is None:
                n = len(v)
            elif len(v) != n:
                raise ValueError("columns must have equal lengths")
        if not n:
            return
        if n > self.free:
            raise BufferError(f"ring buffer full: {len(self)} of {self.capacity} samples held, "
                              f"{n} more requested")
        pos = self.end % self.capacity
        first = min(n, self.capacity - pos)
        for name, v in values.items():
            dst = self._data[name]
            dst[pos:pos + first] = v[:first]
            if first < n:
                dst[:n - first] = v[first:]
        self.end += n

    def consume(self, upto: int) -> None:
        """Forget samples with absolute index < ``upto``."""
        if upto > self.end:
            raise IndexError(f"cannot consume up to {upto}: only {self.end} samples were appended")
        self.start = max(self.start, upto)

    # ------------------------------------------------------------------ read
    def view(self, a: int | None = None, b: int | None = None) -> Mapping[str, np.ndarray]:
        """Columns of absolute samples [a, b) (default: everything held)."""
        a = self.start if a is None else a
        b = self.end if b is None else b
        if a < self.start or b > self.end or a > b:
            raise IndexError(f"samples [{a}, {b}) not held (ring holds [{self.start}, {self.end}))")
        pa, n = a % self.capacity, b - a
        if pa + n <= self.capacity:
            return {k: d[pa:pa + n] for k, d in self._data.items()}
        first = self.capacity - pa
        return {k: np.concatenate([d[pa:], d[:n - first]]) for k, d in self._data.items()}
