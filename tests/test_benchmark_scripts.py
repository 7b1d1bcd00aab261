"""The scripts in benchmarks/ still load against the package: every Python script imports (its
work sits under ``if __name__ == "__main__"``) and every shell script parses. They run on machines
and at sizes that the tests do not reach (a GPU, the paper preset), so this is what catches a
renamed import before device time is spent on it."""

import subprocess
import sys
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
