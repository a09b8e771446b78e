"""Small SVG charts drawn on the server (no script, no library): one value per session, with an
error bar of one standard error where there is one, one colour per series (x, y, z)."""

from __future__ import annotations

import html
import math

COLOURS = {"": "#2b6cb0", "x": "#c53030", "y": "#2f855a", "z": "#2b6cb0"}


def _fmt(v: float) -> str:
    return f"{v:.3g}"


def trend_svg(points, title: str, unit: str, width: int = 340, height: int = 150) -> str:
    """``points``: (session, value, se or None[, series]) tuples. An empty list draws the frame
    with 'no data yet'."""
    left, right, top, bottom = 46, 10, 22, 26
    w, h = width - left - right, height - top - bottom
    out = [f'<svg xmlns="http://www.w3.org/2000/svg" class="chart" width="{width}" '
           f'height="{height}" viewBox="0 0 {width} {height}" role="img" '
           f'aria-label="{html.escape(title)}">',
           f'<text x="{left}" y="14" class="ct">{html.escape(title)} ({html.escape(unit)})</text>',
           f'<rect x="{left}" y="{top}" width="{w}" height="{h}" fill="none" stroke="#bbb"/>']
    pts = [p for p in points if p[1] is not None and math.isfinite(p[1])]
    if not pts:
        out.append(f'<text x="{left + w / 2}" y="{top + h / 2}" text-anchor="middle" '
                   'class="cn">no data yet</text></svg>')
        return "".join(out)
    xs = sorted({p[0] for p in pts})
    lo = min(p[1] - (p[2] or 0) for p in pts)
    hi = max(p[1] + (p[2] or 0) for p in pts)
    if hi - lo < 1e-9:
        lo, hi = lo - 1, hi + 1
    pad = 0.08 * (hi - lo)
    lo, hi = lo - pad, hi + pad

    def X(s):
        return left + (w / 2 if len(xs) == 1 else w * xs.index(s) / (len(xs) - 1))

    def Y(v):
        return top + h * (hi - v) / (hi - lo)

    for v in (lo + pad, hi - pad):
        out.append(f'<text x="{left - 4}" y="{Y(v) + 4:.1f}" text-anchor="end" class="cl">'
                   f'{_fmt(v)}</text>')
    for s in xs:
        out.append(f'<text x="{X(s):.1f}" y="{height - 8}" text-anchor="middle" class="cl">'
                   f'{s}</text>')
    series = sorted({p[3] if len(p) > 3 else "" for p in pts})
    for name in series:
        sp = sorted((p for p in pts if (p[3] if len(p) > 3 else "") == name), key=lambda p: xs.index(p[0]))
        col = COLOURS.get(name, "#555")
        if len(sp) > 1:
            out.append(f'<polyline fill="none" stroke="{col}" stroke-width="1.5" points="'
                       + " ".join(f"{X(p[0]):.1f},{Y(p[1]):.1f}" for p in sp) + '"/>')
        for p in sp:
            x, y = X(p[0]), Y(p[1])
            if p[2]:
                out.append(f'<line x1="{x:.1f}" x2="{x:.1f}" y1="{Y(p[1] - p[2]):.1f}" '
                           f'y2="{Y(p[1] + p[2]):.1f}" stroke="{col}"/>')
            out.append(f'<circle cx="{x:.1f}" cy="{y:.1f}" r="3" fill="{col}">'
                       f'<title>session {p[0]}: {_fmt(p[1])}'
                       + (f' ± {_fmt(p[2])}' if p[2] else '') + f' {html.escape(unit)}</title></circle>')
    if series != [""]:
        for i, name in enumerate(series):
            out.append(f'<text x="{left + w - 10 - 14 * (len(series) - 1 - i)}" y="{top + 12}" '
                       f'fill="{COLOURS.get(name, "#555")}" font-size="11" font-weight="bold">'
                       f'{html.escape(name)}</text>')
    out.append("</svg>")
    return "".join(out)
