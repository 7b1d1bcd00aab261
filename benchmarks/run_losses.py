"""Mean of each logged loss term over the last steps of training runs; prints JSON.

    python benchmarks/run_losses.py BENCH/runs/ours BENCH/runs/ours_no_vc [--last 1000]

Reads each run's ``metrics.jsonl`` (the trainer's log rows: unweighted terms ``gen/*`` and
``dis/*``, their weights ``weight/*``) and reports, per run, the steps logged, and for every
term the mean over the rows of the last ``--last`` steps, and its weighted share
(weight x mean). It answers, e.g., how much a term competes with the adversarial one at the
end of a benchmark's budget (docs/comparison.md).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def run_losses(run: Path, last: int) -> dict:
    rows = [json.loads(line) for line in (Path(run) / "metrics.jsonl").read_text().splitlines() if line.strip()]
    if not rows:
        raise SystemExit(f"run_losses: {run} has no logged steps")
    end = max(r["step"] for r in rows)
    tail = [r for r in rows if r["step"] > end - last]
    terms = sorted({k for r in tail for k in r if k.startswith(("gen/", "dis/")) and not k.endswith("/total")})
    out = {"steps": end, "rows": len(tail), "terms": {}}
    for k in terms:
        values = [r[k] for r in tail if k in r]
        mean = sum(values) / len(values)
        weight = tail[-1].get(f"weight/{k.split('/', 1)[1]}")
        out["terms"][k] = {"mean": round(mean, 4),
                           "weighted": None if weight is None else round(weight * mean, 4)}
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("runs", nargs="+", type=Path)
    ap.add_argument("--last", type=int, default=1000, help="steps at the end of each run to average over")
    args = ap.parse_args(argv)
    for run in args.runs:
        if not (run / "metrics.jsonl").is_file():
            print(f"run_losses: {run} has no metrics.jsonl", file=sys.stderr)
            return 2
    print(json.dumps({"last": args.last, "runs": {str(r): run_losses(r, args.last) for r in args.runs}}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
