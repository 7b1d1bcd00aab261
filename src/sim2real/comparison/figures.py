"""The benchmark's figures and ``report.html``: a bar chart per metric (SVG, with the ceiling and
the floor as reference lines) and the same three views of the test trajectory side by side for
every method, with view 0 once more as the method renders it when the camera revisits it at the
end of the sequence 1..T, T..1."""

from __future__ import annotations

import html
import math
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

from sim2real.comparison.table import markdown
from sim2real.fileio import atomic_write_image, atomic_write_text
from sim2real.grid import tile
from sim2real.inference.anchors import Anchors, stand_in_options
from sim2real.inference.frames import iter_gbuffers
from sim2real.inference.report import blocks_html
from sim2real.inference.svg import COLOURS, fmt_tick, legend_row, nice_ticks
from sim2real.inference.model import load_run
from sim2real.render.reference import reference_rendering, to_uint8
from sim2real.scene.scene import Scene
from sim2real.scene.trajectory import Trajectory

BARS = (("orb_1_accuracy", "ORB-1 accuracy", True), ("orb_5_accuracy", "ORB-5 accuracy", True),
        ("orb_10_accuracy", "ORB-10 accuracy", True), ("orb_1_correct", "ORB-1 correct matches per pair", False),
        ("orb_10_correct", "ORB-10 correct matches per pair", False),
        ("revisit_orb_1_accuracy", "revisit ORB-1 accuracy", True), ("revisit_orb_10_accuracy", "revisit ORB-10 accuracy", True),
        ("of_error", "OF error (px, lower is better)", False), ("revisit_of_error", "revisit OF error (px)", False),
        ("c2st", "C2ST AUC vs held-out real frames (0.5: indistinguishable; lower is better)", False),
        ("dice", "Dice", False), ("detail", "detail: mean grey gradient / the real images'", False), ("fid", "FID (lower is better)", False), ("proxy", "proxy distance (not FID; lower is better)", False))
"""(metric key, chart title, shown in percent)."""


def svg_bar_chart(values: dict[str, float | None], title: str, refs: dict[str, float | None] | None = None,
                  percent: bool = False, width: int = 560, bar_h: int = 18) -> str:
    """Horizontal bars, one per name (None: 'n/a'), with dashed vertical reference lines."""
    refs = {k: v for k, v in (refs or {}).items() if v is not None and math.isfinite(v)}
    vals = [v for v in values.values() if v is not None and math.isfinite(v)] + list(refs.values())
    ml, mr, mt = 130, 20, 30
    H = mt + bar_h * len(values) + 40 + 16 * len(refs)
    out = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{H}" viewBox="0 0 {width} {H}" '
           f'font-family="sans-serif" font-size="11">', f'<rect width="{width}" height="{H}" fill="white"/>',
           f'<text x="{width / 2:.1f}" y="18" text-anchor="middle" font-size="13">{html.escape(title)}</text>']
    ticks = nice_ticks(min(0.0, *vals) if vals else 0.0, max(vals) if vals else 1.0)
    lo, hi = ticks[0], ticks[-1]
    pw = width - ml - mr

    def X(v: float) -> float:
        return ml + (v - lo) / ((hi - lo) or 1.0) * pw

    y_axis = mt + bar_h * len(values)
    for t in ticks:
        out.append(f'<line x1="{X(t):.1f}" y1="{mt}" x2="{X(t):.1f}" y2="{y_axis}" stroke="#eee"/>')
        label = f"{100 * t:g}%" if percent else fmt_tick(t)
        out.append(f'<text x="{X(t):.1f}" y="{y_axis + 14}" text-anchor="middle">{label}</text>')
    for k, (name, v) in enumerate(values.items()):
        y = mt + k * bar_h
        out.append(f'<text x="{ml - 6}" y="{y + bar_h * 0.7:.1f}" text-anchor="end">{html.escape(name)}</text>')
        if v is None or not math.isfinite(v):
            out.append(f'<text x="{ml + 4}" y="{y + bar_h * 0.7:.1f}" fill="#888">n/a</text>')
            continue
        out.append(f'<rect x="{min(X(0), X(v)):.1f}" y="{y + 2}" width="{abs(X(v) - X(0)):.1f}" height="{bar_h - 4}" '
                   f'fill="{COLOURS[k % len(COLOURS)]}"/>')
    for j, (name, v) in enumerate(refs.items()):
        c = "#2ca02c" if name == "ceiling" else "#d62728"
        out.append(f'<line x1="{X(v):.1f}" y1="{mt}" x2="{X(v):.1f}" y2="{y_axis}" stroke="{c}" stroke-dasharray="4 3"/>')
        out.extend(legend_row(ml, y_axis + 26 + 16 * j, c, f"{name} {fmt_tick(v)}", 'stroke-dasharray="4 3"'))
    out.append("</svg>")
    return "\n".join(out)


def _label(text: str, h: int, w: int) -> np.ndarray:
    """A white tile with ``text`` (PIL's default font), for the figure's row names."""
    im = Image.new("RGB", (w, h), "white")
    ImageDraw.Draw(im).text((4, h // 2 - 6), text, fill=(0, 0, 0))
    return np.asarray(im)


def side_by_side(png: Path, runs: dict[str, Path], scene_dir: Path, trajectory: Path, real_dir: Path, seed: int = 0,
                 device: str = "auto") -> dict:
    """``png``: rows a_ref, ceiling, then one per run (name: run folder); columns views 0, T/2, T-1
    of the test trajectory and view 0 revisited at the end of 1..T, T..1. Returns its description."""
    cams = Trajectory.load(trajectory).cameras
    T = len(cams)
    views = [0, T // 2, T - 1]
    gbuffers = list(iter_gbuffers(scene_dir, cams, None, 8))
    scene = Scene.load(scene_dir)
    options, _ = stand_in_options(real_dir)
    anchors = Anchors(scene, seed=seed, options=options)
    rows = {"a_ref": [to_uint8(reference_rendering(gbuffers[v])) for v in views + [0]],
            "ceiling": [anchors.ceiling(gbuffers[v], v) for v in views + [0]]}
    for name, run in runs.items():
        model = load_run(run, device=device)
        seq = model.sequence(scene.name)
        if model.time_independent:  # a frame depends on its own view only: the shown views suffice
            shown = seq.translate([gbuffers[v] for v in views])
            rows[name] = shown + [shown[0]]
            continue
        forward = seq.translate(gbuffers)
        revisit = seq.translate(gbuffers[::-1])[-1]
        rows[name] = [forward[v] for v in views] + [revisit]
    h, w = rows["a_ref"][0].shape[:2]
    grid = tile([[_label(name, h, w), *imgs] for name, imgs in rows.items()])
    atomic_write_image(png, grid)
    return {"file": png.name, "views": views,
            "caption": f"Columns: views {views[0]}, {views[1]}, {views[2]} of the {T}-frame test trajectory, then view 0 "
                       f"as rendered after the camera went to view {T - 1} and back (revisit). Rows: "
                       + ", ".join(rows)}


def write_report(table: dict, out: Path, figure: dict) -> None:
    """``report.html``: the table, a bar chart per metric, the side-by-side views."""
    blocks: list[tuple] = [("h", 1, "sim2real benchmark"), ("pre", markdown(table))]
    names = list(table["methods"])
    for key, title, pct in BARS:
        values = {n: table["methods"][n]["metrics"].get(key) for n in names}
        if all(v is None for v in values.values()):
            continue
        refs = {r: table["anchors"].get(r, {}).get(key) for r in ("ceiling", "floor")}
        blocks.append(("plot", f"plots/{key}.svg", svg_bar_chart(values, title, refs, pct)))
    blocks.append(("h", 2, "The same views, every method"))
    blocks.append(("img", figure["caption"], figure["file"]))
    for blk in blocks:
        if blk[0] == "plot":
            atomic_write_text(out / blk[1], blk[2] + "\n")
    atomic_write_text(out / "report.html", blocks_html(blocks, out, "sim2real benchmark"))
