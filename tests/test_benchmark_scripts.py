"""The scripts in benchmarks/ still load against the package: every Python script imports (its
work sits under ``if __name__ == "__main__"``) and every shell script parses. They run on machines
and at sizes that the tests do not reach (a GPU, the paper preset), so this is what catches a
renamed import before device time is spent on it."""

import subprocess
import sys
import time
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[1] / "benchmarks"


def test_every_python_script_imports():
    names = sorted(p.stem for p in BENCH.glob("*.py"))
    assert "bench_translate" in names and "authors_reference" in names
    code = ("import importlib, sys\n"
            f"sys.path.insert(0, {str(BENCH)!r})\n"
            "bad = []\n"
            f"for name in {names!r}:\n"
            "    try:\n"
            "        importlib.import_module(name)\n"
            "    except Exception as e:\n"
            "        bad.append(f'{name}: {type(e).__name__}: {e}')\n"
            "print('\\n'.join(bad))\n"
            "sys.exit(1 if bad else 0)\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr[-2000:]


@pytest.mark.parametrize("script", sorted(p.name for p in BENCH.glob("*.sh")))
def test_every_shell_script_parses(script):
    r = subprocess.run(["bash", "-n", str(BENCH / script)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr


def test_host_syncs_are_counted_by_source_line(monkeypatch):
    """bench_train's sync count (CUDA only) on the CPU: torch's sync debug mode replaced by a
    recorder, and a step that warns as that mode does from two lines, one of them twice; other
    warnings are not counted, and the mode is switched off again."""
    import warnings

    import torch

    sys.path.insert(0, str(BENCH))
    try:
        import bench_train
    finally:
        sys.path.remove(str(BENCH))
    modes = []
    monkeypatch.setattr(torch.cuda, "set_sync_debug_mode", modes.append)

    def step(s):
        for _ in range(2):
            warnings.warn("called a synchronizing CUDA operation")  # line A, twice a step
        warnings.warn("called a synchronizing CUDA operation")  # line B
        warnings.warn("something else")

    a = step.__code__.co_firstlineno + 2
    got = bench_train.host_syncs(step, [5, 6])
    assert modes == ["warn", 0]
    assert got == {"per_step": 3.0, "steps": 2,
                   "sites": {f"test_benchmark_scripts.py:{a}": 4, f"test_benchmark_scripts.py:{a + 1}": 2}}


def test_device_busy_share_is_the_union_of_activity_over_the_wall_time():
    """bench_train's GPU-busy share: overlapping spans count once (by hand: [0, 20] and [30, 40]
    of 50); and its profiler wiring, run on the CPU's operators: a step that mostly sleeps is
    mostly idle, one that multiplies matrices back to back mostly busy."""
    import torch

    sys.path.insert(0, str(BENCH))
    try:
        import bench_train
    finally:
        sys.path.remove(str(BENCH))
    assert bench_train.busy_share([(5, 20), (0, 10), (30, 40), (32, 35)], 50) == 30 / 50
    assert bench_train.busy_share([], 50) == 0.0
    a = torch.randn(256, 256)
    idle = bench_train.device_busy(lambda s: (time.sleep(0.1), a @ a), [0, 1], device="cpu")
    busy = bench_train.device_busy(lambda s: [a @ a for _ in range(200)], [0, 1], device="cpu")
    assert idle["steps"] == 2 and idle["seconds_per_step"] >= 0.1
    assert idle["busy_share"] < 0.3 < 0.6 < busy["busy_share"] <= 1.0, (idle, busy)


def test_network_flops_are_counted_layer_by_layer(monkeypatch):
    """bench_translate's FLOP count of E_A then G_B, against the layers summed by hand (2 cin cout
    k^2 h w per convolution): 8 filters, two downsamplings, one residual block, 8 content channels,
    an 11-channel 64x128 input. Both up-steps are below the sub-pixel form's break-even, so they
    run (and count) as the direct conv5 on the upsampled image; forced sub-pixel, each counts its
    four 3x3 phase convolutions at the input's size, the reflect border's direct rows and columns,
    and the phase kernels' derivation from the 5x5 weight (per filter pair 2 x 2 phases x 3 x 3
    taps, each a sum over 5 x 5 taps) instead: torch's own einsum order, which opt_einsum, where
    installed, replaces by a cheaper one (a third of those FLOPs here)."""
    import torch
    import torch.backends.opt_einsum

    monkeypatch.setattr(torch.backends.opt_einsum, "enabled", False)

    from sim2real.config import GeneratorConfig
    from sim2real.models.layers import UpConv2dBlock
    from sim2real.models.translator import Translator

    sys.path.insert(0, str(BENCH))
    try:
        import bench_translate
    finally:
        sys.path.remove(str(BENCH))
    conv = lambda cin, cout, k, h, w: 2 * cin * cout * k * k * h * w
    res = 2 * conv(32, 32, 3, 16, 32)
    enc = conv(11, 8, 7, 64, 128) + conv(8, 16, 4, 32, 64) + conv(16, 32, 4, 16, 32) + res + conv(32, 8, 3, 16, 32)
    dec = conv(8, 32, 3, 16, 32) + res + conv(32, 16, 5, 32, 64) + conv(16, 8, 5, 64, 128) + conv(8, 3, 7, 64, 128)
    tr = Translator(8, GeneratorConfig(filters=8, res_blocks=1)).eval()
    x = torch.randn(1, 11, 64, 128)
    run = lambda: tr.dec_b(tr.enc_a(x))
    with torch.no_grad():  # as bench_translate counts (torch 2.5 counts nothing in inference mode)
        assert bench_translate.count_gflop(run) * 1e9 == enc + dec
        ups = [m for m in tr.dec_b.modules() if isinstance(m, UpConv2dBlock)]
        for m in ups:
            m.subpixel = True
        # phases: 4 cout outputs of 3x3 at the input size; border: p = 2 rows top and bottom (width 2w,
        # batch 2 after the cat) and 2 columns left and right (height 2h), direct conv5
        sub = lambda cin, cout, h, w: conv(cin, 4 * cout, 3, h, w) + 2 * conv(cin, cout, 5, 2, 2 * w) \
            + 2 * conv(cin, cout, 5, 2 * h, 2) + 2 * cin * cout * 36 * 25
        subpixel = dec - conv(32, 16, 5, 32, 64) - conv(16, 8, 5, 64, 128) + sub(32, 16, 16, 32) + sub(16, 8, 32, 64)
        assert bench_translate.count_gflop(run) * 1e9 == enc + subpixel
