"""What a training run shows while it runs (rank 0 only).

* a tqdm progress bar (iterations/s, ETA, last total losses);
* TensorBoard scalars in ``RUN/tb``: every unweighted loss term (``gen/<name>``,
  ``dis/<name>``, means over the logging interval), the weighted totals (``gen/total``,
  ``dis/total``), the weight of every term at the logged step (``weight/<name>``), the learning
  rate of every optimiser group (``lr/<group>``) and iterations/s;
* the same scalars as JSON lines in ``RUN/metrics.jsonl``;
* image grids at intervals: ``RUN/samples/step_NNNNNNN.png`` and TensorBoard ``samples``; the
  method chooses the rows (:meth:`sim2real.methods.base.Method.image_rows`). For ``ours``:
  a_ref_i | a_tex_i | b_hat_i | a_rec (ref) | a_cyc (ref); b (real) | a_hat (ref) | a_hat (tex)
  | b_rec | b_cyc; and once L_vc is on, a_ref_j | b_hat_j | w_i(b_hat_j) | b_hat_i on the
  matched pixels | matched mask.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import torch
from torch.utils.tensorboard import SummaryWriter
from tqdm import tqdm

from sim2real.fileio import atomic_write_image, atomic_write_text
from sim2real.grid import tile

GAP = 2


def make_grid(rows: list[list[torch.Tensor]]) -> np.ndarray:
    """Rows of (3, H, W) images in [-1, 1] -> uint8 (H', W', 3) with white gaps; short rows are padded."""
    def u8(img: torch.Tensor) -> np.ndarray:
        return ((img.detach().float().cpu().clamp(-1, 1) + 1) * 127.5 + 0.5).to(torch.uint8).permute(1, 2, 0).numpy()

    return tile([[u8(img) for img in row] for row in rows], GAP)


class Observer:
    def __init__(self, out: Path, total: int, start: int, enabled: bool, progress: bool):
        self.out = Path(out)
        self.enabled = enabled
        self.writer = None
        self.bar = None
        self._sums: dict[str, torch.Tensor] = {}
        self._count = 0
        self._t0 = time.perf_counter()
        self._n0 = start
        if not enabled:
            return

        # after a resume, drop what a killed run logged beyond the checkpoint (TensorBoard: purge_step)
        self.writer = SummaryWriter(str(self.out / "tb"), purge_step=start if start > 0 else None)
        self._truncate_metrics(start)
        self.bar = tqdm(total=total, initial=start, unit="it", desc="train", dynamic_ncols=True,
                        disable=not progress, smoothing=0.1)

    def _truncate_metrics(self, start: int) -> None:
        path = self.out / "metrics.jsonl"
        if start <= 0 or not path.is_file():
            return
        keep = []
        for line in path.read_text().splitlines():
            try:
                if json.loads(line)["step"] <= start:
                    keep.append(line)
            except (ValueError, KeyError, TypeError):
                pass  # a line cut short by a kill
        atomic_write_text(path, "".join(l + "\n" for l in keep))

    def accumulate(self, losses: dict[str, torch.Tensor]) -> None:
        """Add this step's loss terms (device tensors, no sync)."""
        if not self.enabled:
            return
        for k, v in losses.items():
            v = v.detach().float()
            self._sums[k] = self._sums[k] + v if k in self._sums else v.clone()
        self._count += 1

    def step_done(self) -> None:
        if self.bar is not None:
            self.bar.update(1)

    def log(self, step: int, lrs: dict[str, float], extra: dict[str, float]) -> dict[str, float]:
        """Write the interval means (one sync) and return them."""
        if not self.enabled or not self._count:
            return {}
        names = list(self._sums)
        means = (torch.stack([self._sums[k] for k in names]) / self._count).tolist()
        scalars = dict(zip(names, means))
        now = time.perf_counter()
        scalars["time/iterations_per_s"] = (step - self._n0) / max(now - self._t0, 1e-9)
        self._t0, self._n0 = now, step
        scalars.update({f"lr/{k}": v for k, v in lrs.items()})
        scalars.update(extra)
        for k, v in scalars.items():
            self.writer.add_scalar(k, v, step)
        with open(self.out / "metrics.jsonl", "a") as f:
            f.write(json.dumps({"step": step, **scalars}) + "\n")
        if self.bar is not None:
            self.bar.set_postfix(gen=f"{scalars.get('gen/total', 0.0):.3f}", dis=f"{scalars.get('dis/total', 0.0):.3f}",
                                 refresh=False)
        self._sums, self._count = {}, 0
        return scalars

    def images(self, step: int, rows: list[list[torch.Tensor]]) -> Path | None:
        if not self.enabled or not rows:
            return None
        grid = make_grid(rows)
        path = self.out / "samples" / f"step_{step:07d}.png"
        atomic_write_image(path, grid)
        self.writer.add_image("samples", grid, step, dataformats="HWC")
        return path

    def message(self, text: str) -> None:
        if not self.enabled:
            return
        if self.bar is not None and not self.bar.disable:
            self.bar.write(text)
        else:
            print(text)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
        if self.writer is not None:
            self.writer.flush()
            self.writer.close()
