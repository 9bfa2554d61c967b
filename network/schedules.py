"""What each training step uses, as pure functions of the step: learning rate, real-loss weight, samples, pixels.

Resuming a run therefore needs only the step number, and a run split over several processes sees the same data as
one process with the whole batch.

Schedules:

- learning rate (:func:`learning_rate`): linear warm-up over ``warmup`` steps, then a cosine from ``lr`` down to
  ``min_ratio * lr`` at ``total`` steps;
- real-loss weight (:func:`real_loss_weight`): 0 before ``start``, then a linear ramp to ``weight`` over
  ``warmup`` steps (0 at ``start`` itself).

Convention (data order and pixels):
    The samples of epoch ``e`` of a loader are a permutation drawn from ``random.Random(f"{seed}:{loader}:{e}")``;
    the sample at global position ``k`` is that of epoch ``k // n``, slot ``k % n`` (:func:`sample_order`). Step
    ``s`` on rank ``r`` of ``W`` with per-rank batch ``B`` takes positions ``(s W + r) B + j``, ``j < B``
    (:class:`StepBatches`): the ranks see disjoint slices, and a ``W``-process run with batch ``B`` sees the same
    samples at every step as a 1-process run with batch ``W B``. Sample ``j`` of a batch draws its pixels from its
    own generator seeded with :func:`pixel_seed` ``(seed, loader, step, position)`` (:func:`sample_batch_pixels`),
    so a sample gets the same pixels however the global batch is split over processes. E.g. with ``W = 2``,
    ``B = 1``, step 3 of rank 1 takes position 7.
"""

from __future__ import annotations

import hashlib
import math
import random
from collections.abc import Iterator

import torch
from torch.utils.data import Sampler

from .model.sampling import sample_pixels

__all__ = [
    "StepBatches",
    "learning_rate",
    "pixel_seed",
    "real_loss_weight",
    "rewarm_factor",
    "sample_batch_pixels",
    "sample_order",
]


def learning_rate(step: int, lr: float, warmup: int, total: int, min_ratio: float = 0.1) -> float:
    """Learning rate of (0-based) ``step``: linear warm-up, then cosine decay.

    ``lr * (step + 1) / warmup`` for ``step < warmup``; afterwards
    ``lr * (m + (1 - m) (1 + cos(pi t)) / 2)`` with ``t = (step - warmup) / (total - warmup)``
    clipped to [0, 1] and ``m = min_ratio`` (constant ``lr`` when ``total <= warmup``).

    Example:
        >>> learning_rate(0, 1.0, 4, 12), learning_rate(4, 1.0, 4, 12), learning_rate(12, 1.0, 4, 12, 0.1)
        (0.25, 1.0, 0.1)
    """
    if step < warmup:
        return lr * (step + 1) / warmup
    if total <= warmup:
        return lr
    t = min(1.0, (step - warmup) / (total - warmup))
    return lr * (min_ratio + (1.0 - min_ratio) * 0.5 * (1.0 + math.cos(math.pi * t)))


def rewarm_factor(step: int, start: int, steps: int) -> float:
    """Learning-rate factor of a re-warm: ``(step - start + 1) / steps`` from ``start``, 1 before and after.

    A chunk that resumes with a fresh optimizer (:mod:`network.chunk_state`) ramps its learning rate
    again while Adam's moment estimates settle; ``steps`` 0 turns it off.

    Example:
        >>> [rewarm_factor(s, 10, 4) for s in (9, 10, 11, 13, 14)]
        [1.0, 0.25, 0.5, 1.0, 1.0]
    """
    if steps <= 0 or not start <= step < start + steps:
        return 1.0
    return (step - start + 1) / steps


def real_loss_weight(step: int, weight: float, start: int, warmup: int) -> float:
    """Weight of the real loss at ``step``: 0 before ``start``, a linear ramp to ``weight`` over ``warmup`` steps.

    ``weight * clip((step - start) / warmup, 0, 1)`` (a step at ``step >= start`` when ``warmup`` is 0), so the
    weight is still 0 at ``step = start`` and reaches ``weight`` at ``start + warmup``.

    Example:
        >>> [real_loss_weight(s, 0.1, 2, 4) for s in (0, 2, 3, 6, 9)]
        [0.0, 0.0, 0.025, 0.1, 0.1]
    """
    if step < start:
        return 0.0
    if warmup == 0:
        return float(weight)
    return float(weight) * min(1.0, (step - start) / warmup)


def pixel_seed(seed: int, loader: str, step: int, position: int) -> int:
    """Seed of the pixel-sampling generator of the sample at global data ``position`` in ``step``.

    Args:
        seed: The run's seed.
        loader: The loader's name (``"synthetic"`` or ``"real"``).
        step: The 0-based optimizer step.
        position: The global data position.

    Returns:
        A seed in [0, 2**63).
    """
    digest = hashlib.blake2b(f"{seed}:{loader}:{step}:{position}".encode(), digest_size=8).digest()
    return int.from_bytes(digest, "little") >> 1  # torch seeds are < 2**63 here


def sample_order(n: int, seed: int, loader: str, position: int) -> int:
    """Dataset index at global data ``position`` (a fresh permutation of ``range(n)`` every epoch).

    Args:
        n: Dataset size.
        seed: The run's seed.
        loader: The loader's name.
        position: The global data position.

    Returns:
        The dataset index in ``[0, n)``.

    Example:
        >>> sorted(sample_order(4, 0, "synthetic", k) for k in range(4))  # one epoch: each sample once
        [0, 1, 2, 3]
    """
    epoch, slot = divmod(position, n)
    return _epoch_permutation(n, seed, loader, epoch)[slot]


_PERMUTATIONS: dict[tuple[int, int, str, int], list[int]] = {}


def _epoch_permutation(n: int, seed: int, loader: str, epoch: int) -> list[int]:
    key = (n, seed, loader, epoch)
    if key not in _PERMUTATIONS:
        if len(_PERMUTATIONS) > 64:
            _PERMUTATIONS.clear()
        order = list(range(n))
        random.Random(f"{seed}:{loader}:{epoch}").shuffle(order)
        _PERMUTATIONS[key] = order
    return _PERMUTATIONS[key]


class StepBatches(Sampler):
    """Batches of dataset indices for the given steps, this rank's slice of the global batch.

    Args:
        n: Dataset size.
        seed: The run's seed.
        loader: The loader's name (``"synthetic"`` or ``"real"``).
        steps: The steps to yield batches for, in order.
        batch: Samples per step and rank.
        rank: This process's rank.
        world: Number of processes.

    Example:
        >>> StepBatches(10, 0, "synthetic", [3], batch=1, rank=1, world=2).positions(3)
        [7]
    """

    def __init__(self, n: int, seed: int, loader: str, steps: list[int], batch: int, rank: int, world: int) -> None:
        self.n, self.seed, self.loader, self.steps = n, seed, loader, steps
        self.batch, self.rank, self.world = batch, rank, world

    def positions(self, step: int) -> list[int]:
        """Global data positions of this rank's samples in ``step``."""
        first = (step * self.world + self.rank) * self.batch
        return list(range(first, first + self.batch))

    def __iter__(self) -> Iterator[list[int]]:
        for step in self.steps:
            yield [sample_order(self.n, self.seed, self.loader, p) for p in self.positions(step)]

    def __len__(self) -> int:
        return len(self.steps)


def sample_batch_pixels(mask: torch.Tensor, count: int, seeds: list[int]) -> tuple[torch.Tensor, torch.Tensor]:
    """Per-sample :func:`~network.model.sampling.sample_pixels` with its own generator; padded with invalid pixels.

    Args:
        mask: ``(B, 1, H, W)`` on the CPU.
        count: pixels per image.
        seeds: one generator seed per sample.

    Returns:
        ``pixels (B, P)`` long and ``valid (B, P)`` bool, ``P`` = the largest per-sample count.
    """
    parts = [sample_pixels(mask[i : i + 1], count, torch.Generator().manual_seed(s)) for i, s in enumerate(seeds)]
    p = max(px.shape[1] for px, _ in parts)
    pixels = torch.zeros(len(seeds), p, dtype=torch.long)
    valid = torch.zeros(len(seeds), p, dtype=torch.bool)
    for i, (px, ok) in enumerate(parts):
        pixels[i, : px.shape[1]], valid[i, : px.shape[1]] = px[0], ok[0]
    return pixels, valid
