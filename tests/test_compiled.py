"""sim2real.inference.compiled on its own: a compile on the CPU prints nothing of CUDA."""

import os
import subprocess
import sys


def test_cpu_compile_is_quiet_about_a_cuda_toolkit(tmp_path):
    """torch warns once, as its compiler stack loads, that a CUDA toolkit (CUDA_HOME) was found
    without a CUDA runtime; a CPU compile says nothing of it. A fresh process, with CUDA_HOME
    naming a folder, so that the warning is due."""
    (tmp_path / "cuda").mkdir()
    code = ("import torch\n"
            "from sim2real.inference.compiled import compile_networks\n"
            "m = torch.nn.Conv2d(3, 3, 3)\n"
            "assert compile_networks([m], torch.device('cpu')) == 1\n"
            "with torch.inference_mode():\n"
            "    y = m(torch.ones(1, 3, 8, 8))\n"
            "print(tuple(y.shape))\n")
    env = {**os.environ, "CUDA_HOME": str(tmp_path / "cuda"), "SIM2REAL_CACHE": str(tmp_path / "cache")}
    env.pop("TORCHINDUCTOR_CACHE_DIR", None)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.strip() == "(1, 3, 6, 6)"
    assert "CUDA" not in r.stderr, r.stderr
    assert (tmp_path / "cache" / "inductor").is_dir()  # the compiled code is cached under SIM2REAL_CACHE
