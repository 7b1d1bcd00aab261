"""The evaluation report: ``report.md`` (plots as SVG files, samples as PNG files beside it) and a
self-contained ``report.html`` (inline SVG plots, sample images embedded as data URIs).

Plots are hand-written SVG (:mod:`sim2real.inference.svg`).
"""

from __future__ import annotations

import base64
import html
import json
from pathlib import Path

from sim2real.fileio import atomic_write_text
from sim2real.inference.svg import svg_line_plot

# --- formatting ----------------------------------------------------------------------------------


def _num(v, digits: int = 4) -> str:
    if v is None:
        return "n/a"
    if isinstance(v, float):
        return f"{v:.{digits}g}"
    return str(v)


def _orb_cell(e: dict) -> str:
    if e["pairs"] == 0:
        return "n/a (no pairs)"
    acc = "n/a" if e["accuracy"] is None else f"{100 * e['accuracy']:.1f}%"
    return f"{acc} ({e['mean_correct']:.1f})"


def _segmenters(m: dict) -> str:
    n = len(m["dice_info"].get("classes") or {})
    return "liver U-Nets" if n <= 1 else f"U-Nets of {n} classes (the liver's Dice)"


def _dice_row(m: dict, row: str, label: str, note: str) -> list[str]:
    d = m["dice_info"].get("rows", {}).get(row)
    if d is None:
        return [label, "n/a", m["reasons"]["dice"] or "not computed"]
    spread = "" if d["spread"] is None else f" (seeds {', '.join(f'{v:.3f}' for v in d['per_seed'])})"
    value = _num(d["value"]) + (f" ± {d['stderr']:.3f}" if d.get("stderr") else "")  # its standard error
    return [label, value, (d["reason"] or note) + spread]


_DICE_ROW_NAMES = {"model": "translated views", "a_ref": "a_ref (untranslated)", "ceiling": "ceiling"}


def class_dice_blocks(m: dict) -> list[tuple]:
    """With segmenters of several classes: each class's Dice on every row's frames and on the
    held-out real images (mean over the seeds); nothing with the liver alone."""
    info = m["dice_info"]
    per_class = info.get("class_dice")
    if not per_class:
        return []
    rows_shown = list(next(iter(per_class.values())))
    table = []
    for c, by_row in per_class.items():
        held = [s["held_out_dice_classes"][c] for s in info.get("per_seed", [])
                if (s.get("held_out_dice_classes") or {}).get(c) is not None]
        table.append([c] + [_num(by_row[r]) for r in rows_shown] + [_num(sum(held) / len(held) if held else None)])
    return [("h", 3, "Dice per class"),
            ("p", "The same segmenters, one output per class the real labels and the scenes share; n/a for a "
                  "class in none of the views (its Dice would measure nothing). The liver's is the Dice above."),
            ("table", ["class"] + [_DICE_ROW_NAMES.get(r, r) for r in rows_shown] + ["held-out real images"], table)]


def _blocks(m: dict, samples: dict[str, str]) -> list[tuple]:
    """The report as neutral blocks: ('h', level, text) ('p', text) ('table', header, rows)
    ('plot', file, svg, caption) ('img', caption, rel) ('pre', text)."""
    r = m["reasons"]
    run = m["run"]
    b: list[tuple] = [("h", 1, "sim2real evaluation")]
    what = (f"The video {run['frames']} (made by any tool along the trajectory), evaluated on {run['device']} at its "
            f"cameras' size {run['train_height']}×{run['train_width']}. " if run.get("frames") else
            f"Run {run['dir']} — checkpoint {run['checkpoint']} (step {run['step']}, method '{run['method']}'), "
            f"evaluated on {run['device']} at the training size {run['train_height']}×{run['train_width']}. ")
    b.append(("p", what +
                   f"Scenes: {', '.join(s['name'] for s in m['inputs']['scenes'])}. "
                   f"Real images: {m['inputs']['real']['dir']} ({m['inputs']['real']['images_used']} used of "
                   f"{m['inputs']['real']['images']}; {m['inputs']['real']['labelled']} labelled)."))

    for w in m.get("warnings", []):
        b.append(("p", f"**Note:** {w}."))
    b += realism_beside_blocks(m)
    if m.get("position"):
        b += _calibration_blocks(m)
    b.append(("h", 2, "Realism"))
    fk = m["fid_kid"]
    kid = "n/a" if m["kid_mean"] is None else f"{m['kid_mean']:.4f} ± {m['kid_std']:.4f}"
    rows = [
        ["FID", _num(m["fid"]), r["fid"] or f"{fk['n_gen']} generated vs {fk['n_real']} real images, FID Inception weights {fk['weights']}"],
        ["KID (mean ± std)", kid, r["fid"] or f"{fk['kid_subsets']} subsets of {fk['kid_subset_size']}"],
        _dice_row(m, "model", "Dice, translated views",
                  f"mean over {m['dice_info'].get('seeds', 1)} {_segmenters(m)} trained on {m['dice_info']['n_train']} labelled "
                  f"real images, evaluated on {m['dice_info']['n_eval']} views"),
        _dice_row(m, "a_ref", "Dice, reference rendering a_ref (untranslated)", "the same segmenters on the simulated input"),
        _dice_row(m, "ceiling", "Dice, ceiling (the stand-in on the simulated views)", "real look, simulated labels"),
        ["Dice, held-out real images", _num(m.get("dice_real_held_out")),
         r["dice"] if not m["dice_info"].get("held_out_dice") else
         (m["dice_info"]["held_out_dice"]["reason"] or f"{m['dice_info'].get('n_held_out', 0)} images not trained on")],
        ["Dice, its own real training images (fit check)", _num(m["dice_real_train"]),
         (r["dice"] if m["dice_real_train"] is None else "not held out")],
        ["proxy colour+texture distance (**not FID**)", _num(m["proxy"]["proxy_colour_texture_distance"]),
         f"colour {m['proxy']['proxy_colour_distance']:.4f} + texture {m['proxy']['proxy_texture_distance']:.4f}; "
         f"a cheap stand-in, 0 for identical statistics"],
    ]
    if m["fid"] is None:
        b.append(("p", f"FID and KID are not reported: {r['fid']}"))
    b.append(("table", ["metric", "value", "note"], rows))
    b += class_dice_blocks(m)

    b.append(("h", 2, "Temporal consistency"))
    b.append(("p", "ORB-k: accuracy of cross-checked ORB matches between frames k apart (correct when the two 3D points "
                   f"are < {m['settings']['threshold_mm']:g} mm apart), with the mean number of correct matches per pair in "
                   "brackets. OF: mean absolute difference between the geometric flow and Farnebäck flow of consecutive "
                   "translated frames over visible pixels, in pixels (lower is better)."))
    rows = [[f"ORB-{k}", _orb_cell(m["orb"][k]), _orb_cell(m["revisit"]["orb"][k]), str(m["orb"][k]["pairs"])] for k in m["orb"]]
    rows.append(["OF error (px)", _num(m["of_error"]), _num(m["revisit"]["of_error"]), ""])
    b.append(("table", ["metric", "forward", "revisit (1..T, T..1)", "pairs"], rows))
    notes = [f"{k}: {v}" for k, v in r.items() if v and k in ("of_error", "orb", "revisit")]
    if notes:
        b.append(("p", "Not computable: " + " | ".join(notes)))
    b.append(("p", f"Revisit protocol: backward half {m['revisit']['backward_frames']}; for a time-independent "
                   "model it equals the forward metric."))
    rows = []
    for name, s in m["per_scene"].items():
        mr = s["rows"]["model"]
        rows.append([name, str(s["frames"]), _num(mr["of_error"])] + [_orb_cell(mr["orb_curve"][k]) for k in m["orb"]])
    b.append(("table", ["scene", "frames", "OF error"] + [f"ORB-{k}" for k in m["orb"]], rows))

    b += odometry_blocks(m)
    ks = [int(k) for k in m["orb_curve"]]
    curves = m.get("row_curves") or {"model": m["orb_curve"]}
    acc = {row: [(k, c[str(k)]["accuracy"]) for k in ks] for row, c in curves.items() if row != "a_ref"}
    cor = {row: [(k, c[str(k)]["mean_correct"]) for k in ks] for row, c in curves.items() if row != "a_ref"}
    b.append(("h", 3, "ORB-k curve"))
    b.append(("plot", "plots/orb_accuracy.svg", svg_line_plot(acc, "ORB-k accuracy", "k (frames apart)", "accuracy",
                                                               y_min=0.0, y_max=1.0, y_percent=True), "ORB-k accuracy"))
    b.append(("plot", "plots/orb_correct.svg", svg_line_plot(cor, "Correct ORB matches per pair", "k (frames apart)",
                                                              "correct matches / pair", y_min=0.0), "correct matches per pair"))
    first = next(iter(m["per_scene"].values()))
    of = {row: [(t, e) for t, e in enumerate(r["per_pair"]["of_error"])] for row, r in first["rows"].items()}
    b.append(("plot", "plots/of_error.svg", svg_line_plot(of, "OF error per frame pair", "frame t (pair t, t+1)",
                                                           "OF error (px)", y_min=0.0), "OF error per frame pair"))

    if samples:
        b.append(("h", 2, "Samples"))
        for caption, rel in samples.items():
            b.append(("img", caption, rel))
    b.append(("h", 2, "Settings"))
    b.append(("pre", json.dumps({"settings": m["settings"], "seconds": m["seconds"]}, indent=2)))
    return b


_BESIDE = [("orb_1_correct", "ORB-1 correct / pair", "higher"), ("orb_10_correct", "ORB-10 correct / pair", "higher"),
           ("of_error", "OF error (px)", "lower")]
_BESIDE_REALISM = [("c2st", "C2ST AUC (0.5 = as real)"), ("random_kid", "KID, random-net features (0 = as real)"),
                   ("dice", "Dice"), ("fid", "FID"), ("kid", "KID (Inception)"),
                   ("proxy", "proxy colour+texture (not FID)")]
_ROW_LABELS = {"model": "model", "ceiling": "ceiling (a perfect video)", "floor": "floor (a flickering video)",
               "a_ref": "a_ref (untranslated)", "real_held_out": "real images (held out)"}


def realism_beside_blocks(m: dict) -> list[tuple]:
    """Every row's consistency figures beside its realism measures: a high ORB count with poor
    realism reads as what it is."""
    rows_ = m["rows"]
    real = m.get("realism", {})
    shown = [(k, label) for k, label in _BESIDE_REALISM
             if k in real and any(v is not None for v in real[k]["rows"].values())]
    header = ["row"] + [f"{label} ({better})" for _, label, better in _BESIDE] + \
             [f"{label} ({real[k]['better']})" for k, label in shown]
    table = []
    for r in list(rows_) + ["real_held_out"]:
        cons = [_num(rows_[r].get(k), 3) if r in rows_ else "" for k, _, _ in _BESIDE]
        table.append([_ROW_LABELS.get(r, r)] + cons + [_num(real[k]["rows"].get(r), 3) for k, _ in shown])
    b: list[tuple] = [("h", 2, "Consistency beside realism"),
                      ("p", "Consistency counts reward any pattern that stays on the surface, realistic or not; the "
                            "realism measures say whether the frames look like the real images. Read them together. "
                            "C2ST and KID compare each row with half of the real images; the other half "
                            "(real images, held out) shows the value of real frames themselves. FID and the proxy "
                            "compare each row with all the real images; their real row is one half against the "
                            "other. C2ST: held-out AUC "
                            "of a small CNN trained to tell the row's frames from real ones (0.5: it cannot, 1: "
                            "always); "
                            "KID in the features of a fixed random network (0: the same distribution)."),
                      ("table", header, table)]
    notes = [f"{k}: {real[k]['reason']}" for k in ("c2st", "random_kid") if k in real and real[k].get("reason")]
    if notes:
        b.append(("p", "Not computed: " + " | ".join(notes)))
    return b


def odometry_blocks(m: dict) -> list[tuple]:
    """The downstream odometry table: per row, success rate and median errors for k = 1, 5, 10."""
    odo = m.get("odometry") or {}
    if not odo.get("rows"):
        return []
    b: list[tuple] = [("h", 3, "Downstream odometry"),
                      ("p", f"Two-view relative pose between frames k apart ({odo['method']}). A success is {odo['success']}; "
                            f"a pair without a pose counts as a failure and as a 180° error in the medians. At most "
                            f"{odo['pairs_per_k']} pairs per k, evenly spaced.")]
    table = []
    for row, per_k in odo["rows"].items():
        cells = []
        for k, e in per_k.items():
            rate = "n/a" if e["success_rate"] is None else f"{100 * e['success_rate']:.0f}%"
            cells.append(f"{rate} ({_num(e['median_rotation_error_deg'], 2)}° / {_num(e['median_translation_error_deg'], 2)}°)")
        table.append([_ROW_LABELS.get(row, row)] + cells)
    ks = list(next(iter(odo["rows"].values())))
    b.append(("table", ["row"] + [f"k = {k}: success (median rotation / translation direction error)" for k in ks],
              table))
    return b


_CAL_METRICS = [
    ("orb_1_accuracy", "ORB-1 accuracy", True), ("orb_1_correct", "ORB-1 correct / pair", False),
    ("orb_5_accuracy", "ORB-5 accuracy", True), ("orb_5_correct", "ORB-5 correct / pair", False),
    ("orb_10_accuracy", "ORB-10 accuracy", True), ("orb_10_correct", "ORB-10 correct / pair", False),
    ("of_error", "OF error (px, paper; vs ground truth)", False), ("of_epe", "OF end-point error (px, vs ground truth)", False),
    ("of_error_vs_ceiling", "OF error vs the ceiling's flow (px)", False),
    ("of_epe_vs_ceiling", "OF end-point error vs the ceiling's flow (px)", False),
    ("revisit_orb_1_accuracy", "revisit ORB-1 accuracy", True), ("revisit_orb_10_accuracy", "revisit ORB-10 accuracy", True),
    ("revisit_of_error", "revisit OF error (px)", False),
    ("dice", "Dice (mean over segmenter seeds)", False), ("proxy", "proxy colour+texture distance (not FID)", False),
    ("detail", "detail: mean grey gradient / the real images'", True),
    ("fid", "FID", False), ("kid", "KID", False),
    ("c2st", "C2ST AUC (0.5 = as real)", False), ("random_kid", "KID in random-network features", False),
]


def _cal_value(v, pct: bool) -> str:
    if v is None:
        return "n/a"
    return f"{100 * v:.1f}%" if pct else f"{v:.4g}"


def _pos_cell(p: dict, key: str) -> str:
    v, why = p.get(key), p.get("reason" if key == "position" else "reason_a_ref") or ""
    if v is not None:
        return _num(v, 3)
    if why.startswith("above"):
        return "above the stand-in's level"
    if "no ceiling exists" in why:
        return "no ceiling"
    if why.startswith("uncalibrated"):
        return "uncalibrated"
    return "n/a"


def _calibration_blocks(m: dict) -> list[tuple]:
    rows_ = m["rows"]
    pos = m["position"]
    cal = m.get("calibration", {})
    b: list[tuple] = [("h", 2, "Between floor and ceiling")]
    if cal.get("status") == "no ceiling":
        b.append(("p", "**No ceiling exists for this real domain.** The ceiling and the floor below are the stand-in "
                       "domain rendered on the same views, not your footage: positions are withheld. Read the model "
                       "against the floor (flicker) and a_ref (the untranslated input) for consistency, and against "
                       "the realism measures above, which compare with your own images."))
    elif cal.get("status") == "uncalibrated":
        b.append(("p", f"**Uncalibrated path:** on this path the ceiling does not clear the floor and a_ref by "
                       f"{cal['margin']:.0%} on {', '.join(cal['uncalibrated'])}; those positions are withheld."))
    b.append(("p", "Every metric is also computed on three reference videos of the very same views and path: the "
                   "**ceiling** (the stand-in real domain rendered with one appearance: consistent and detailed by "
                   "construction, the best these metrics can say of a video here), the **floor** (the same with a new "
                   "appearance every frame: it flickers) and **a_ref**, the untranslated input. Position = (model − "
                   "floor) / (ceiling − floor): 0 is the floor, 1 the ceiling; n/a where the ceiling and the floor differ "
                   "by less than 5 %, i.e. the metric cannot tell them apart (the per-frame realism metrics do not see "
                   "flicker: read their position from a_ref). A model beyond the ceiling is \"above the stand-in's "
                   "level\", not a fraction: the ceiling is what the stand-in scores, not an upper bound."))
    table = []
    for key, label, pct in _CAL_METRICS:
        if key not in rows_["model"] or all(rows_[r].get(key) is None for r in rows_):
            continue
        p = pos.get(key, {})
        table.append([label] + [_cal_value(rows_[r].get(key), pct) for r in ("model", "ceiling", "floor", "a_ref")]
                     + [_pos_cell(p, "position"), _pos_cell(p, "position_a_ref")])
    b.append(("table", ["metric", "model", "ceiling", "floor", "a_ref", "position (floor 0, ceiling 1)",
                        "position (a_ref 0, ceiling 1)"], table))
    mot = []
    for name, s in m["per_scene"].items():
        mo = s["motion"]
        ov = mo["overlap"]
        mot.append([name, str(s["frames"]), _num(mo["flow_px_per_frame_median"], 3),
                    f"{100 * mo['flow_frac_per_frame_median']:.2f}%" if mo["flow_frac_per_frame_median"] is not None else "n/a",
                    _num(mo["deg_per_frame_max"], 3)] + [_cal_value(ov.get(k), True) for k in ("1", "5", "10")])
    b.append(("p", "Motion of the test path, measured on it (ground-truth flow, rotation, and the share of a frame "
                   "still in view k frames later):"))
    b.append(("table", ["scene", "frames", "median flow / frame (px)", "of the width", "max rotation / frame (°)",
                        "overlap 1", "overlap 5", "overlap 10"], mot))
    return b


def _md(blocks: list[tuple]) -> str:
    lines: list[str] = []
    for blk in blocks:
        kind = blk[0]
        if kind == "h":
            lines += ["#" * blk[1] + " " + blk[2], ""]
        elif kind == "p":
            lines += [blk[1], ""]
        elif kind == "table":
            header, rows = blk[1], blk[2]
            lines.append("| " + " | ".join(header) + " |")
            lines.append("|" + "---|" * len(header))
            for row in rows:
                lines.append("| " + " | ".join(str(c).replace("|", "\\|") for c in row) + " |")
            lines.append("")
        elif kind == "plot":
            lines += [f"![{blk[3]}]({blk[1]})", ""]
        elif kind == "img":
            lines += [blk[1], "", f"![{blk[1]}]({blk[2]})", ""]
        elif kind == "pre":
            lines += ["```json", blk[1], "```", ""]
    return "\n".join(lines)


def _inline_md(text: str) -> str:
    """html-escape, keeping **bold**."""
    parts = html.escape(text).split("**")
    return "".join(f"<b>{p}</b>" if i % 2 else p for i, p in enumerate(parts))


def blocks_html(blocks: list[tuple], out: Path, title: str = "sim2real evaluation") -> str:
    """A self-contained HTML page of report ``blocks`` (images of ``out`` inlined)."""
    body: list[str] = []
    for blk in blocks:
        kind = blk[0]
        if kind == "h":
            body.append(f"<h{blk[1]}>{html.escape(blk[2])}</h{blk[1]}>")
        elif kind == "p":
            body.append(f"<p>{_inline_md(blk[1])}</p>")
        elif kind == "table":
            head = "".join(f"<th>{html.escape(h)}</th>" for h in blk[1])
            rows = "".join("<tr>" + "".join(f"<td>{_inline_md(str(c))}</td>" for c in row) + "</tr>" for row in blk[2])
            body.append(f"<table><thead><tr>{head}</tr></thead><tbody>{rows}</tbody></table>")
        elif kind == "plot":
            body.append(f'<figure>{blk[2]}</figure>')
        elif kind == "img":
            data = base64.b64encode((out / blk[2]).read_bytes()).decode("ascii")
            body.append(f'<figure><img src="data:image/png;base64,{data}" alt="{html.escape(blk[1])}">'
                        f"<figcaption>{html.escape(blk[1])}</figcaption></figure>")
        elif kind == "pre":
            body.append(f"<pre>{html.escape(blk[1])}</pre>")
    style = ("body{font-family:sans-serif;max-width:1100px;margin:2em auto;padding:0 1em;color:#222}"
             "table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #ccc;padding:4px 8px;text-align:left}"
             "th{background:#f3f3f3}figure{margin:1em 0}img{max-width:100%;image-rendering:pixelated}"
             "pre{background:#f6f6f6;padding:1em;overflow:auto}")
    return ("<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\">"
            f"<title>{html.escape(title)}</title>"
            f"<style>{style}</style></head><body>\n" + "\n".join(body) + "\n</body></html>\n")


def write_report(metrics: dict, out: str | Path, samples: dict[str, str]) -> None:
    """Write ``report.md`` (+ ``plots/*.svg``) and the self-contained ``report.html`` into ``out``."""
    out = Path(out)
    blocks = _blocks(metrics, samples)
    for blk in blocks:
        if blk[0] == "plot":
            atomic_write_text(out / blk[1], blk[2] + "\n")
    atomic_write_text(out / "report.md", _md(blocks))
    atomic_write_text(out / "report.html", blocks_html(blocks, out))
