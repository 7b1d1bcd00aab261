"""Line plots as hand-written SVG (no plotting library is a dependency of the project), for the
evaluation report and the comparison's figures."""

from __future__ import annotations

import html
import math
from typing import Sequence

COLOURS = ("#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f")


# --- SVG line plots ------------------------------------------------------------------------------


def nice_ticks(lo: float, hi: float, n: int = 5) -> list[float]:
    if not (math.isfinite(lo) and math.isfinite(hi)) or hi <= lo:
        hi = lo + 1.0
    raw = (hi - lo) / max(n, 1)
    mag = 10 ** math.floor(math.log10(raw))
    step = next(m * mag for m in (1, 2, 2.5, 5, 10) if m * mag >= raw)
    start = math.floor(lo / step) * step
    ticks, t = [], start
    while t <= hi + 1e-9 * step:
        ticks.append(round(t, 10))
        t += step
    if ticks[-1] < hi - 1e-9 * step:  # the axis ends on a tick above the data
        ticks.append(round(ticks[-1] + step, 10))
    return ticks


def fmt_tick(v: float) -> str:
    return f"{v:g}" if abs(v) >= 1e-3 or v == 0 else f"{v:.1e}"


def legend_row(x: float, y: float, colour: str, label: str, stroke: str = "") -> list[str]:
    """One legend entry at (x, y): a 20-px line in ``colour`` (extra ``stroke`` attributes) and
    ``label`` beside it."""
    extra = f" {stroke}" if stroke else ""
    return [f'<line x1="{x}" y1="{y}" x2="{x + 20}" y2="{y}" stroke="{colour}"{extra}/>',
            f'<text x="{x + 26}" y="{y + 4}">{html.escape(label)}</text>']


def svg_line_plot(series: dict[str, Sequence[tuple[float, float | None]]], title: str, xlabel: str, ylabel: str,
                  width: int = 560, height: int = 320, y_min: float | None = None, y_max: float | None = None,
                  y_percent: bool = False) -> str:
    """A line plot as an SVG string. ``series``: name -> [(x, y or None)]; None breaks the line."""
    pts = [(x, y) for s in series.values() for x, y in s if y is not None and math.isfinite(y)]
    ml, mr, mt, mb = 62, 16, 30, 46
    legend_h = 16 * len(series)
    H = height + legend_h
    out = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{H}" viewBox="0 0 {width} {H}" '
           f'font-family="sans-serif" font-size="11">',
           f'<rect width="{width}" height="{H}" fill="white"/>',
           f'<text x="{width / 2:.1f}" y="18" text-anchor="middle" font-size="13">{html.escape(title)}</text>']
    if not pts:
        out.append(f'<text x="{width / 2:.1f}" y="{height / 2:.1f}" text-anchor="middle" fill="#888">no data</text></svg>')
        return "\n".join(out)
    xs = [p[0] for p in pts]
    ys = [p[1] for p in pts]
    x0, x1 = min(xs), max(xs)
    if x1 == x0:
        x0, x1 = x0 - 1, x1 + 1
    lo = min(ys) if y_min is None else y_min
    hi = max(ys) if y_max is None else y_max
    if hi <= lo:
        hi = lo + (abs(lo) or 1.0)
    yt = nice_ticks(lo, hi)
    lo, hi = min(lo, yt[0]), max(hi, yt[-1])
    pw, ph = width - ml - mr, height - mt - mb

    def X(x: float) -> float:
        return ml + (x - x0) / (x1 - x0) * pw

    def Y(y: float) -> float:
        return mt + ph - (y - lo) / (hi - lo) * ph

    out.append(f'<rect x="{ml}" y="{mt}" width="{pw}" height="{ph}" fill="none" stroke="#444"/>')
    for t in yt:
        label = f"{100 * t:g}%" if y_percent else fmt_tick(t)
        out.append(f'<line x1="{ml}" y1="{Y(t):.1f}" x2="{ml + pw}" y2="{Y(t):.1f}" stroke="#ddd"/>')
        out.append(f'<text x="{ml - 5}" y="{Y(t) + 4:.1f}" text-anchor="end">{label}</text>')
    for t in nice_ticks(x0, x1, 10):
        if x0 - 1e-9 <= t <= x1 + 1e-9:
            out.append(f'<line x1="{X(t):.1f}" y1="{mt + ph}" x2="{X(t):.1f}" y2="{mt + ph + 4}" stroke="#444"/>')
            out.append(f'<text x="{X(t):.1f}" y="{mt + ph + 16}" text-anchor="middle">{fmt_tick(t)}</text>')
    out.append(f'<text x="{ml + pw / 2:.1f}" y="{mt + ph + 34}" text-anchor="middle">{html.escape(xlabel)}</text>')
    out.append(f'<text transform="translate(14 {mt + ph / 2:.1f}) rotate(-90)" text-anchor="middle">{html.escape(ylabel)}</text>')
    for k, (name, s) in enumerate(series.items()):
        c = COLOURS[k % len(COLOURS)]
        runs, cur = [], []
        for x, y in s:
            if y is None or not math.isfinite(y):
                if cur:
                    runs.append(cur)
                cur = []
            else:
                cur.append((X(x), Y(y)))
        if cur:
            runs.append(cur)
        for r in runs:
            if len(r) > 1:
                d = " ".join(f"{a:.1f},{b:.1f}" for a, b in r)
                out.append(f'<polyline points="{d}" fill="none" stroke="{c}" stroke-width="1.8"/>')
            for a, b in r:
                out.append(f'<circle cx="{a:.1f}" cy="{b:.1f}" r="2.4" fill="{c}"/>')
        out.extend(legend_row(ml, height + 4 + 16 * k, c, name, 'stroke-width="2"'))
    out.append("</svg>")
    return "\n".join(out)
