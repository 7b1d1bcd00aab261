"""``sim2real doctor``: each check against states made by hand (no GPU is needed to see what it
says of one), the figures computed by hand, and the command's JSON and exit status."""

import json
import types
from pathlib import Path

import torch

from sim2real import doctor
from sim2real.cli.main import main
from sim2real.errors import UserError

MiB, GiB = 2**20, 2**30
NAMES = ["torch", "gpu", "cpu", "shm", "cache", "compile", "video", "fid", "blend"]


def test_gpu_states(monkeypatch):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    monkeypatch.setattr(doctor, "_nvidia_driver", lambda: True)
    monkeypatch.setattr(torch.version, "cuda", None)
    c = doctor.check_gpu()
    assert c.status == "warn" and "CPU build" in c.text and "install a CUDA build of torch" in c.text
    monkeypatch.setattr(torch.version, "cuda", "12.6")
    c = doctor.check_gpu()
    assert c.status == "warn" and "CUDA 12.6" in c.text and "sees no device" in c.text
    monkeypatch.setattr(doctor, "_nvidia_driver", lambda: False)
    assert doctor.check_gpu().status == "note"  # no GPU at all: the CPU is a fallback, not a fault

    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 2)
    monkeypatch.setattr(torch.cuda, "get_device_properties",
                        lambda k: types.SimpleNamespace(name=f"GPU{k}", total_memory=int(139.8 * GiB)))
    monkeypatch.setattr(torch.cuda, "is_bf16_supported", lambda: True)
    c = doctor.check_gpu()
    assert c.status == "ok" and c.figures["devices"] == [{"name": "GPU0", "memory_gib": 139.8},
                                                         {"name": "GPU1", "memory_gib": 139.8}]
    monkeypatch.setattr(torch.cuda, "is_bf16_supported", lambda: False)
    assert doctor.check_gpu().status == "warn"


def test_shared_memory_by_hand(monkeypatch):
    """Paper size, 256x512: a pair in transit is (2 x 26 + 9 + 3) bytes a pixel + 4096 =
    8,392,704 bytes; two ahead per worker: 16,785,408. 15 workers wanted (a 16-core host):
    64 MiB x 0.8 holds 3 of them, and all 15 need 15 x 16,785,408 / 0.8 bytes = 300 MiB."""
    monkeypatch.setattr(doctor, "loader_workers", lambda workers: 15)
    c = doctor.check_shared_memory(free=64 * MiB)
    assert c.status == "warn" and c.figures["workers_started"] == 3 and c.figures["per_worker_mib"] == 16.0
    assert "holds 3 of 15" in c.text and "training starts 3" in c.text and "about 300 MiB" in c.text
    c = doctor.check_shared_memory(free=16 * MiB)  # 12.8 MiB usable: not one worker
    assert c.status == "warn" and c.figures["workers_started"] == 0 and "training stops" in c.text
    c = doctor.check_shared_memory(free=GiB)  # 858 MB usable: 51 workers' worth
    assert c.status == "ok" and c.figures["workers_started"] == 15


def test_cache_disk_by_hand(monkeypatch, tmp_path):
    """A paper view pool: 3,000 views x (256 x 512 pixels x 18 bytes + a 128-byte camera)
    = 7,078,272,000 bytes (6.59 GiB). The cache folder need not exist yet: its disk is asked."""
    asked = []

    def usage(path):
        asked.append(Path(path))
        return types.SimpleNamespace(free=free)

    monkeypatch.setattr(doctor.shutil, "disk_usage", usage)
    free = 20 * GiB
    c = doctor.check_cache(tmp_path / "not" / "yet")
    assert asked == [tmp_path] and c.status == "ok"
    assert c.figures["pools_fit"] == 3 and c.figures["view_pool_gib"] == round(7_078_272_000 / GiB, 2)
    free = 5 * GiB
    c = doctor.check_cache(tmp_path)
    assert c.status == "warn" and c.figures["pools_fit"] == 0 and "data.view_pool=0" in c.text


def test_compiler_states(monkeypatch):
    from sim2real.inference import compiled

    monkeypatch.delenv("CXX", raising=False)
    monkeypatch.setattr(doctor.shutil, "which", lambda name: None)
    assert doctor.check_compiler(False, torch.device("cpu")).status == "note"
    monkeypatch.setattr(doctor.shutil, "which", lambda name: "/usr/bin/" + name)
    c = doctor.check_compiler(False, torch.device("cpu"))
    assert c.status == "ok" and c.figures["available"] is None and "not probed" in c.text

    def fails(device):
        raise UserError(f"--compile: TorchInductor cannot compile for {device} (no compiler)")

    monkeypatch.setattr(compiled, "check_compiler", fails)
    c = doctor.check_compiler(True, torch.device("cpu"))
    assert c.status == "note" and c.figures["available"] is False and "cannot compile for cpu" in c.text
    monkeypatch.setattr(compiled, "check_compiler", lambda device: None)
    assert doctor.check_compiler(True, torch.device("cpu")).figures == {"available": True, "probed": True}


def test_fid_weights_states(monkeypatch, tmp_path):
    monkeypatch.delenv("SIM2REAL_FID_WEIGHTS", raising=False)
    assert doctor.check_fid().status == "note"  # absent: realism falls back to the weight-free tests
    monkeypatch.setenv("SIM2REAL_FID_WEIGHTS", str(tmp_path / "missing.pth"))
    c = doctor.check_fid()
    assert c.status == "warn" and "missing.pth" in c.text


def test_command_json_and_exit_status(capsys):
    code = main(["doctor", "--json"])
    checks = json.loads(capsys.readouterr().out)
    assert list(checks) == NAMES
    assert all(c["status"] in ("ok", "note", "warn") and c["text"] for c in checks.values())
    assert code == (1 if any(c["status"] == "warn" for c in checks.values()) else 0)
    assert checks["cpu"]["figures"]["cores"] >= 1


def test_command_lines(capsys):
    """One line a check, in order: status, name, text."""
    main(["doctor"])
    lines = capsys.readouterr().out.splitlines()
    assert [line.split()[1] for line in lines] == NAMES
    assert all(line.split()[0] in ("ok", "note", "warn") for line in lines)
