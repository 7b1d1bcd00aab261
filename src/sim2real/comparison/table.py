"""Table 1 of the paper from the evaluations of a benchmark: ``table.json`` and ``table.md``.

Columns as in the paper: method, type (img / vid / ours), realism, Dice, OF error, and ORB-1/5/10
as accuracy with the correct matches per frame pair in brackets; beside them the weight-free
realism measure (the classifier two-sample test's AUC, 0.5 = indistinguishable from held-out real
frames) and the odometry success rates (k = 1/5/10), so that a high ORB count with poor realism
reads as what it is. FID and KID need Inception weights; without them the named proxy distance
stands in. Each method also has its revisit figures (OF and ORB on the sequence 1..T, T..1); a
time-dependent method gets its own "(revisit)" row, as OF-UNIT does in the paper, and for a
time-independent one they equal the forward figures.

A method trained with several seeds shows the mean over its runs with their range in brackets;
``table.json`` keeps every run. The reference rows close the table: the ceiling (a perfect video),
the floor (a flickering one), a_ref (the simulation's own rendering), scored on the same views and
paths, and the real held-out frames for realism. The path's calibration (the ceiling clears the
floor and a_ref, :func:`sim2real.inference.rows.calibration`) is stated under the table; every
method's position between floor and ceiling is in ``table.json`` where it calibrates.
"""

from __future__ import annotations

import statistics
from pathlib import Path

from sim2real.fileio import atomic_write_json, atomic_write_text
from sim2real.inference.rows import PAPER_KS, positions
from sim2real.methods import get_method

KINDS = {"views": "img", "triplets": "vid", "view_pairs": "ours"}
"""The paper's 'type' column by the data a method trains on."""
REFERENCE_ROWS = ("ceiling", "floor", "a_ref", "real_held_out")
REALISM = "c2st"
"""The weight-free realism measure of the table (metrics/twosample.py)."""


def _kind(cfg) -> str:
    method = get_method(cfg)
    if method.data == "views" and getattr(cfg.method, "texture", None) is not None and cfg.method.texture.features:
        return "ours"  # the texture without view consistency (ours_no_vc)
    return KINDS.get(method.data, method.data)


def _row(m: dict, row: str) -> dict:
    """The figures of one row of one evaluation: its metrics, realism and odometry success rates."""
    out = dict(m["rows"].get(row, {}))
    if row == "model":
        out.update(fid=m["fid"], kid=m["kid_mean"])
    realism = m.get("realism", {}).get(REALISM, {}).get("rows", {})
    if row in realism:
        out[REALISM] = realism[row]
    proxy = m.get("realism", {}).get("proxy", {}).get("rows", {})
    if row == "real_held_out" and proxy.get(row) is not None:  # the other rows carry theirs
        out["proxy"] = proxy[row]
    odo = m.get("odometry", {}).get("rows", {}).get(row, {})
    for k, v in odo.items():
        out[f"odometry_{k}_success"] = v.get("success_rate")
    return out


def _mean(rows: list[dict]) -> tuple[dict, dict]:
    """Per key: the mean over the runs' rows and the (min, max) range (None where a run has none)."""
    mean, spread = {}, {}
    for key in rows[0]:
        vals = [r.get(key) for r in rows]
        if any(v is None or not isinstance(v, (int, float)) for v in vals):
            mean[key] = rows[0][key] if len(rows) == 1 else None
            continue
        mean[key] = statistics.fmean(vals)
        if len(vals) > 1:
            spread[key] = [min(vals), max(vals)]
    return mean, spread


def build_table(metrics: dict[str, dict], trained: dict[str, dict], configs: dict,
                methods: dict[str, str] | None = None) -> dict:
    """``table.json``'s content from each run's ``metrics.json`` and training record.

    ``methods`` maps a run name to its method (several seeds of one method); default: each run
    is its own method. The first run's evaluation holds the reference rows."""
    methods = methods or {name: name for name in metrics}
    first = next(iter(metrics.values()))
    anchors = {r: _row(first, r) for r in REFERENCE_ROWS
               if r in first["rows"] or r in first.get("realism", {}).get(REALISM, {}).get("rows", {})}
    calibration = first.get("calibration", {})
    entries = {}
    for method in dict.fromkeys(methods.values()):
        runs = [n for n in metrics if methods[n] == method]
        rows = [_row(metrics[n], "model") for n in runs]
        row, spread = _mean(rows)
        cfg = configs[runs[0]]
        entry = {"type": _kind(cfg), "time_independent": get_method(cfg).time_independent,
                 "runs": {n: {"seed": configs[n].seed, "train": trained[n], "step": metrics[n]["run"]["step"],
                              "metrics": r} for n, r in zip(runs, rows)},
                 "train": trained[runs[0]], "metrics": row, "range": spread}
        if {"ceiling", "floor", "a_ref"} <= set(anchors):
            pos = positions({"model": row, **{r: anchors[r] for r in ("ceiling", "floor", "a_ref")}},
                            calibration.get("metrics"))
            entry["position"] = {k: v["position"] for k, v in pos.items()}
        entries[method] = entry
    return {"format": "sim2real-table/2", "realism": "fid" if first["fid"] is not None else "proxy",
            "realism_reason": first["reasons"]["fid"], "methods": entries, "anchors": anchors,
            "calibration": calibration, "evaluation": {"settings": first["settings"], "inputs": first["inputs"]}}


def _num(v, digits: int = 3) -> str:
    return "–" if v is None else f"{v:.{digits}g}"


def _with_range(row: dict, spread: dict, key: str, fmt) -> str:
    v = row.get(key)
    if v is None:
        return fmt(None)
    return fmt(v) + (f" ({fmt(spread[key][0])}–{fmt(spread[key][1])})" if key in spread else "")


def _cells(row: dict, realism: str, spread: dict | None = None, revisit: bool = False,
           ceiling: dict | None = None) -> list[str]:
    """The table cells after 'type'; a revisit row has only OF and ORB (realism is per frame). An
    ORB count above the ``ceiling`` row's gets a ``⁺``: above the stand-in's level, not a fraction of it."""
    spread, ceiling = spread or {}, ceiling or {}
    pre = "revisit_" if revisit else ""
    num = lambda key: _with_range(row, spread, key, _num)  # noqa: E731
    frame = ["fid", "kid"] if realism == "fid" else ["proxy"]
    cells = ["–"] * (len(frame) + 2) if revisit else [num(REALISM), *map(num, frame), num("dice")]
    cells.append(num(f"{pre}of_error"))
    for k in PAPER_KS:
        acc, count, top = row.get(f"{pre}orb_{k}_accuracy"), row.get(f"{pre}orb_{k}_correct"), ceiling.get(f"orb_{k}_correct")
        above = "⁺" if count is not None and top is not None and count > top else ""
        cells.append("no match" if acc is None else
                     f"{_with_range(row, spread, f'{pre}orb_{k}_accuracy', lambda v: f'{100 * v:.1f} %')} "
                     f"({num(f'{pre}orb_{k}_correct')}{above})")
    odo = [row.get(f"odometry_{k}_success") for k in PAPER_KS]
    cells.append("–" if revisit or all(v is None for v in odo) else
                 " / ".join("–" if v is None else f"{100 * v:.0f}" for v in odo) + " %")
    return cells


def markdown(table: dict) -> str:
    realism = table["realism"]
    head = ["method", "type", "C2ST AUC ↓", *(["FID ↓", "KID ↓"] if realism == "fid" else ["proxy ↓ (not FID)"]),
            "Dice ↑", "OF ↓", *[f"ORB-{k} ↑" for k in PAPER_KS], "odometry k=1/5/10 ↑"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    ceiling = table["anchors"].get("ceiling")
    for name, e in table["methods"].items():
        seeds = f" ×{len(e['runs'])}" if len(e.get("runs", {})) > 1 else ""
        lines.append("| " + " | ".join([name + seeds, e["type"],
                                        *_cells(e["metrics"], realism, e.get("range"), ceiling=ceiling)]) + " |")
        if not e["time_independent"]:
            lines.append("| " + " | ".join([f"{name}{seeds} (revisit)", e["type"],
                                            *_cells(e["metrics"], realism, e.get("range"), True, ceiling)]) + " |")
    for r in REFERENCE_ROWS:
        if r in table["anchors"]:
            lines.append("| " + " | ".join([f"*{r.replace('_', ' ')}*", "", *_cells(table["anchors"][r], realism)]) + " |")
    notes = ["", "C2ST AUC: a small classifier's AUC at telling the frames from held-out real ones (0.5: it "
             "cannot). ORB-k: accuracy (correct matches per frame pair). OF: Farnebäck vs ground-truth flow, px. "
             "Odometry: share of frame pairs k apart whose relative pose is recovered (docs/evaluation.md).",
             "Time-independent methods' revisit figures equal their forward ones (table.json has them for every "
             "method). *ceiling*: the stand-in real domain rendered with one appearance; *floor*: a new appearance "
             "every frame; *a ref*: the simulation's own rendering; on the same views and paths. ×N: mean of N "
             "seeds, their range in brackets. ⁺: more correct matches than the ceiling, i.e. above the stand-in's "
             "level: features fixed to the surface, which say nothing of realism (read the C2ST beside them)."]
    cal = table.get("calibration") or {}
    if cal.get("status") == "calibrated":
        notes.append(f"The test path calibrates: the ceiling clears the floor and a_ref by {cal['margin']:.0%} "
                     "on the ORB-1/5/10 counts and the OF error.")
    elif cal.get("status"):
        notes.append(f"The test path does not calibrate ({cal['status']}: {', '.join(cal.get('uncalibrated', []))}); "
                     "positions between floor and ceiling are withheld there.")
    if realism != "fid":
        notes.append(f"FID/KID not reported: {table['realism_reason']}")
    notes.append("Training: " + "; ".join(f"{n} {r['train']['iterations']} it in {r['train']['seconds']:.0f} s"
                                          for e in table["methods"].values()
                                          for n, r in e.get("runs", {"": {"train": e["train"]}}).items()))
    return "\n".join(lines + notes) + "\n"


def write_table(table: dict, out: Path) -> None:
    atomic_write_json(Path(out) / "table.json", table)
    atomic_write_text(Path(out) / "table.md", markdown(table))
