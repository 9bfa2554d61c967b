"""Tests of network/distributed.py in one process (the multi-process case: tests/network/test_ddp.py)."""

import pytest
import torch

from network.distributed import DistContext, init_distributed, resolve_device, rng_state, set_rng_state


def test_single_process_collectives_are_no_ops(monkeypatch):
    monkeypatch.delenv("WORLD_SIZE", raising=False)
    dd, device = init_distributed(torch.device("cpu"))
    assert dd == DistContext() and not dd.active and device == torch.device("cpu")
    dd.barrier()
    assert dd.any_true(True, device) and not dd.any_true(False, device)
    assert dd.mean([1.0, 2.0], device) == [1.0, 2.0] and dd.gather("x") == ["x"]


def test_devices_and_rng_state():
    assert resolve_device("cpu") == torch.device("cpu")
    if not torch.cuda.is_available():
        assert resolve_device("auto") == torch.device("cpu")
        with pytest.raises(ValueError, match="CUDA is not available"):
            resolve_device("cuda")
    state = rng_state(torch.device("cpu"))
    a = torch.rand(3)
    set_rng_state(state, torch.device("cpu"))
    assert torch.equal(torch.rand(3), a)
