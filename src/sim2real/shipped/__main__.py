"""Pack a finished run as the shipped demo model (maintainers; see the package docstring):

  python -m sim2real.shipped RUN --scores ROW.json [--preset cpu-lines] [--seed 0] [--out FOLDER]

RUN was trained on ``make_embedded_data(DIR, seed, ...)`` (e.g. by benchmarks/detail_study.py);
ROW.json holds what it scored (e.g. the study's row) and how it was trained (key ``trained``);
``--preset`` names the preset it was trained with (its config must equal it outside
``shipped.RUN_KEYS``), written beside the weights as ``demo_model.yaml``.
"""

import argparse
import json
import sys
from pathlib import Path

from sim2real import shipped
from sim2real.errors import UserError
from sim2real.fileio import read_json


def main() -> int:
    ap = argparse.ArgumentParser(prog="python -m sim2real.shipped", description=__doc__.splitlines()[0])
    ap.add_argument("run", type=Path)
    ap.add_argument("--scores", type=Path, required=True)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=shipped.HERE)
    ap.add_argument("--preset", default=shipped.PRESET, help="the preset the run was trained with")
    args = ap.parse_args()
    try:
        record = shipped.pack(args.run, args.seed, read_json(args.scores, "scores"), args.out,
                              preset_name=args.preset)
    except UserError as e:
        print(f"pack: error: {e}", file=sys.stderr)
        return 2
    print(json.dumps({k: v for k, v in record.items() if k != "reference"}, indent=1))
    return 0


sys.exit(main())
