"""Distributed training helpers: the process group under ``torchrun``, collectives, devices and RNG states.

Under ``torchrun`` (``WORLD_SIZE > 1``) :func:`init_distributed` initialises the process group from the environment
(``gloo`` on the CPU, ``nccl`` on CUDA, one GPU per local rank). :class:`DistContext` wraps the few collectives
training needs and turns them into no-ops in a single process.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any

import torch
import torch.distributed as dist

__all__ = ["DistContext", "init_distributed", "resolve_device", "rng_state", "set_rng_state"]


@dataclass
class DistContext:
    """This process's place in the run, and the collectives training uses (no-ops when ``world == 1``).

    Attributes:
        rank: Global rank.
        world: Number of processes.
        local_rank: Rank on this node (the CUDA device index).
        owned: Whether :func:`init_distributed` created the process group (and training must destroy it).

    Example:
        >>> DistContext().mean([1.0, 3.0], torch.device("cpu"))  # one process: unchanged
        [1.0, 3.0]
    """

    rank: int = 0
    world: int = 1
    local_rank: int = 0
    owned: bool = False

    @property
    def active(self) -> bool:
        """True in a multi-process run."""
        return self.world > 1

    def barrier(self) -> None:
        """Wait for every rank."""
        if self.active:
            dist.barrier()

    def any_true(self, flag: bool, device: torch.device) -> bool:
        """True on every rank when ``flag`` is True on any rank."""
        if not self.active:
            return flag
        t = torch.tensor([1.0 if flag else 0.0], device=device)
        dist.all_reduce(t, op=dist.ReduceOp.MAX)
        return bool(t.item() > 0)

    def mean(self, values: list[float], device: torch.device) -> list[float]:
        """The element-wise mean of ``values`` over the ranks (in float64)."""
        if not self.active:
            return values
        t = torch.tensor(values, dtype=torch.float64, device=device)
        dist.all_reduce(t)
        return (t / self.world).tolist()

    def gather(self, obj: Any) -> list[Any]:
        """Every rank's ``obj``, in rank order."""
        if not self.active:
            return [obj]
        out: list[Any] = [None] * self.world
        dist.all_gather_object(out, obj)
        return out


def resolve_device(name: str) -> torch.device:
    """The device of ``--device`` ``name``: ``"cpu"``, ``"cuda"`` or ``"auto"`` (CUDA when available).

    Raises:
        ValueError: If ``name`` is ``"cuda"`` and CUDA is not available.
    """
    if name == "cuda" and not torch.cuda.is_available():
        raise ValueError("device cuda: CUDA is not available on this machine (use --device cpu or auto)")
    return torch.device("cuda" if name == "cuda" or (name == "auto" and torch.cuda.is_available()) else "cpu")


def init_distributed(device: torch.device) -> tuple[DistContext, torch.device]:
    """Join the ``torchrun`` process group (when ``WORLD_SIZE > 1``) and pick this rank's device.

    Args:
        device: The requested device; on CUDA, this rank uses device ``LOCAL_RANK``.

    Returns:
        The context and the device to use.
    """
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world <= 1:
        return DistContext(), device
    local_rank = int(os.environ.get("LOCAL_RANK", "0"))
    if device.type == "cuda":
        torch.cuda.set_device(local_rank)
        device = torch.device("cuda", local_rank)
    owned = not dist.is_initialized()
    if owned:
        dist.init_process_group(backend="nccl" if device.type == "cuda" else "gloo", init_method="env://")
    return DistContext(dist.get_rank(), dist.get_world_size(), local_rank, owned), device


def rng_state(device: torch.device) -> dict[str, torch.Tensor | None]:
    """This process's torch (and, on CUDA, the device's) RNG state, for a checkpoint."""
    return {"torch": torch.get_rng_state(), "cuda": torch.cuda.get_rng_state(device) if device.type == "cuda" else None}


def set_rng_state(state: dict, device: torch.device) -> None:
    """Restore a state from :func:`rng_state`."""
    torch.set_rng_state(state["torch"])
    if device.type == "cuda" and state.get("cuda") is not None:
        torch.cuda.set_rng_state(state["cuda"], device)
