"""Table 1 of the paper from the evaluations of a benchmark: ``table.json`` and ``table.md``.

Columns as in the paper: method, type (img / vid / ours), FID and KID (or the named proxy
distance when no Inception weights were given), Dice, OF error, and ORB-1/5/10 as accuracy with
the correct matches per frame pair in brackets. Each method also has its revisit figures (OF and
ORB on the sequence 1..T, T..1); a time-dependent method gets its own "(revisit)" row, as
OF-UNIT does in the paper, and for a time-independent one they equal the forward figures. The
ceiling (a perfect video) and the floor (a flickering one), scored on the same views and paths,
close the table, and every method's position between them is in ``table.json``.
"""

from __future__ import annotations

from pathlib import Path

from sim2real.fileio import atomic_write_json, atomic_write_text
from sim2real.inference.rows import PAPER_KS, positions
from sim2real.methods import get_method

KINDS = {"views": "img", "triplets": "vid", "view_pairs": "ours"}
"""The paper's 'type' column by the data a method trains on."""


def _kind(cfg) -> str:
    method = get_method(cfg)
    if method.data == "views" and getattr(cfg.method, "texture", None) is not None and cfg.method.texture.features:
        return "ours"  # the texture without view consistency (ours_no_vc)
    return KINDS.get(method.data, method.data)


def build_table(metrics: dict[str, dict], trained: dict[str, dict], configs: dict) -> dict:
    """``table.json``'s content from each method's ``metrics.json`` and training record."""
    first = next(iter(metrics.values()))
    anchors = {r: first["rows"][r] for r in ("ceiling", "floor", "a_ref") if r in first["rows"]}
    methods = {}
    for name, m in metrics.items():
        row = dict(m["rows"]["model"])
        row.update(fid=m["fid"], kid=m["kid_mean"])
        entry = {"type": _kind(configs[name]), "time_independent": get_method(configs[name]).time_independent,
                 "train": trained[name], "metrics": row, "step": m["run"]["step"]}
        if {"ceiling", "floor", "a_ref"} <= set(anchors):
            entry["position"] = {k: v["position"] for k, v in positions({"model": row, **anchors}).items()}
        methods[name] = entry
    return {"format": "sim2real-table/1", "realism": "fid" if first["fid"] is not None else "proxy",
            "realism_reason": first["reasons"]["fid"], "methods": methods, "anchors": anchors,
            "evaluation": {"settings": first["settings"], "inputs": first["inputs"]}}


def _num(v, digits: int = 3) -> str:
    return "–" if v is None else f"{v:.{digits}g}"


def _orb(acc, correct) -> str:
    return "no match" if acc is None else f"{100 * acc:.1f} % ({_num(correct, 2)})"


def _cells(row: dict, realism: str, revisit: bool = False) -> list[str]:
    """The table cells after 'type'; a revisit row has only OF and ORB (realism is per frame)."""
    pre = "revisit_" if revisit else ""
    if revisit:
        cells = ["–"] * (3 if realism == "fid" else 2)
    elif realism == "fid":
        cells = [_num(row.get("fid")), _num(row.get("kid")), _num(row.get("dice"))]
    else:
        cells = [_num(row.get("proxy")), _num(row.get("dice"))]
    cells.append(_num(row.get(f"{pre}of_error")))
    return cells + [_orb(row.get(f"{pre}orb_{k}_accuracy"), row.get(f"{pre}orb_{k}_correct")) for k in PAPER_KS]


def markdown(table: dict) -> str:
    realism = table["realism"]
    head = ["method", "type", *(["FID ↓", "KID ↓"] if realism == "fid" else ["proxy distance ↓ (not FID)"]),
            "Dice ↑", "OF ↓", *[f"ORB-{k} ↑" for k in PAPER_KS]]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for name, e in table["methods"].items():
        lines.append("| " + " | ".join([name, e["type"], *_cells(e["metrics"], realism)]) + " |")
        if not e["time_independent"]:
            lines.append("| " + " | ".join([f"{name} (revisit)", e["type"], *_cells(e["metrics"], realism, True)]) + " |")
    for r in ("ceiling", "floor"):
        if r in table["anchors"]:
            lines.append("| " + " | ".join([f"*{r}*", "", *_cells(table["anchors"][r], realism)]) + " |")
    notes = ["", "ORB-k: accuracy (correct matches per frame pair). OF: Farnebäck vs ground-truth flow, px.",
             "Time-independent methods' revisit figures equal their forward ones (table.json has them for every "
             "method). *ceiling*: the stand-in real domain rendered with one appearance; *floor*: a new appearance "
             "every frame, on the same views and paths."]
    if realism != "fid":
        notes.append(f"FID/KID not reported: {table['realism_reason']}")
    budgets = {name: e["train"] for name, e in table["methods"].items()}
    notes.append("Training: " + "; ".join(f"{n} {b['iterations']} it in {b['seconds']:.0f} s" for n, b in budgets.items()))
    return "\n".join(lines + notes) + "\n"


def write_table(table: dict, out: Path) -> None:
    atomic_write_json(Path(out) / "table.json", table)
    atomic_write_text(Path(out) / "table.md", markdown(table))
