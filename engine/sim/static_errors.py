"""The static sensor-error model of the six-orientation calibration (Oh et al. 2024, spec §5.1).

r = (diag(G) + M) u + o + n: per-axis offset o (g), gain G, cross-axis term M (off-diagonal,
a symmetric part = non-orthogonality and an antisymmetric part = a small rotation) and white
noise of SD sigma (g). ``draw`` gives Table-2-like values (offsets up to ±0.2 g, gains
0.99-1.015, |M| up to 0.025, sigma 0.5-5 mg); ``coupling_max`` adds symmetric cross-axis
coupling alone (M_ij = M_ji, non-orthogonal axes; MEMS data sheets allow up to 1-2 %).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np


@dataclass
class StaticErrors:
    offset_g: list = field(default_factory=lambda: [0.0, 0.0, 0.0])
    gain: list = field(default_factory=lambda: [1.0, 1.0, 1.0])
    symmetric: list = field(default_factory=lambda: [0.0, 0.0, 0.0])  # M_xy, M_xz, M_yz (sym part)
    antisymmetric: list = field(default_factory=lambda: [0.0, 0.0, 0.0])  # rotation part
    noise_g: list = field(default_factory=lambda: [0.0, 0.0, 0.0])  # SD per axis

    @property
    def matrix(self) -> np.ndarray:
        """S = diag(G) + M (rows: measured axes)."""
        s = np.diag(np.asarray(self.gain, np.float64))
        for (i, j), a, b in zip(((0, 1), (0, 2), (1, 2)), self.symmetric, self.antisymmetric):
            s[i, j] += a + b
            s[j, i] += a - b
        return s

    def measure(self, u_g: np.ndarray, rng=None) -> np.ndarray:
        """Readings (n, 3) in g from true specific force ``u_g`` (n, 3) in g."""
        r = np.asarray(u_g, np.float64) @ self.matrix.T + np.asarray(self.offset_g)
        if rng is not None and np.any(np.asarray(self.noise_g) > 0):
            r = r + rng.standard_normal(r.shape) * np.asarray(self.noise_g)
        return r

    def to_dict(self) -> dict:
        d = asdict(self)
        d["matrix"] = self.matrix.tolist()
        return d

    @staticmethod
    def from_dict(d: dict) -> "StaticErrors":
        known = StaticErrors.__dataclass_fields__
        return StaticErrors(**{k: v for k, v in d.items() if k in known})

    @staticmethod
    def ideal() -> "StaticErrors":
        return StaticErrors()

    @staticmethod
    def draw(rng, *, offset_max_g: float = 0.2, gain_range=(0.99, 1.015), cross_max: float = 0.0,
             noise_range_g=(0.0005, 0.005), coupling_max: float = 0.0) -> "StaticErrors":
        """Table-2-like errors (cross-axis terms off unless ``cross_max``: symmetric and
        antisymmetric parts each within ±cross_max/2; or ``coupling_max``: symmetric terms
        only, each within ±coupling_max; the two add)."""
        e = StaticErrors(
            offset_g=list(rng.uniform(-offset_max_g, offset_max_g, 3)),
            gain=list(rng.uniform(*gain_range, 3)),
            symmetric=list(rng.uniform(-cross_max, cross_max, 3) / 2),
            antisymmetric=list(rng.uniform(-cross_max, cross_max, 3) / 2),
            noise_g=list(rng.uniform(*noise_range_g, 3)))
        if coupling_max:
            e.symmetric = list(np.asarray(e.symmetric)
                               + rng.uniform(-coupling_max, coupling_max, 3))
        return e
