"""sim2real.engine.device.resolve_device: the device chosen at run time."""

import pytest
import torch

from sim2real.engine.device import resolve_device
from sim2real.errors import UserError


def test_auto_and_cpu_without_cuda(monkeypatch):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert resolve_device("auto") == torch.device("cpu")
    assert resolve_device("cpu", local_rank=3) == torch.device("cpu")
    with pytest.raises(UserError, match="no CUDA device is available"):
        resolve_device("cuda")


def test_cuda_takes_the_rank_modulo_the_devices(monkeypatch):
    """Ranks 0..5 on a host with 4 devices: rank 5 shares device 1; 'auto' picks CUDA too; the
    chosen device becomes the current one (set_device)."""
    current = []
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 4)
    monkeypatch.setattr(torch.cuda, "set_device", current.append)
    assert resolve_device("cuda", local_rank=5) == torch.device("cuda", 1)
    assert resolve_device("auto", local_rank=2) == torch.device("cuda", 2)
    assert current == [torch.device("cuda", 1), torch.device("cuda", 2)]


def test_other_names_are_refused():
    with pytest.raises(UserError, match="got 'gpu'"):
        resolve_device("gpu")
