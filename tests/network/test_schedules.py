"""Tests of network/schedules.py: learning rate, real-loss weight, data order and pixel seeds."""

import numpy as np
import pytest
import torch

from network.schedules import (
    StepBatches,
    learning_rate,
    pixel_seed,
    real_loss_weight,
    sample_batch_pixels,
    sample_order,
)


def test_learning_rate_warmup_then_cosine():
    lr, warm, total, m = 2e-3, 4, 14, 0.1
    got = [learning_rate(s, lr, warm, total, m) for s in range(20)]
    # Warm-up: lr * (s + 1) / warm, reaching the peak at the last warm-up step.
    np.testing.assert_allclose(got[:4], [0.5e-3, 1e-3, 1.5e-3, 2e-3], rtol=1e-12)
    # Cosine: peak at s = warm, halfway (s = 9) the mean of peak and floor, floor from s = total on.
    assert got[4] == pytest.approx(lr)
    assert got[9] == pytest.approx(lr * (1 + m) / 2)
    assert got[14:] == pytest.approx([lr * m] * 6)
    assert all(a >= b for a, b in zip(got[3:], got[4:], strict=False))  # non-increasing after warm-up
    assert learning_rate(7, lr, 0, 0) == lr  # no horizon: constant


def test_real_weight_ramp():
    w = [real_loss_weight(s, 0.2, 3, 4) for s in range(10)]
    # 0 up to and including the start, then 0.2 * (s - 3) / 4, capped at 0.2.
    np.testing.assert_allclose(w, [0, 0, 0, 0, 0.05, 0.1, 0.15, 0.2, 0.2, 0.2], rtol=1e-12, atol=0)
    assert [real_loss_weight(s, 0.1, 2, 0) for s in range(4)] == [0.0, 0.0, 0.1, 0.1]  # no ramp: a step


def test_data_order_does_not_depend_on_the_process_split():
    # 2 ranks with batch 1 see, step by step, the samples that 1 process with batch 2 sees.
    n, seed, steps = 5, 3, list(range(6))
    one = list(StepBatches(n, seed, "synthetic", steps, batch=2, rank=0, world=1))
    ranks = [list(StepBatches(n, seed, "synthetic", steps, batch=1, rank=r, world=2)) for r in range(2)]
    assert one == [a + b for a, b in zip(*ranks, strict=True)]
    # Every epoch is a permutation; different epochs (and loaders) are shuffled independently.
    epochs = [[sample_order(n, seed, "synthetic", e * n + k) for k in range(n)] for e in range(3)]
    assert all(sorted(e) == list(range(n)) for e in epochs) and len({tuple(e) for e in epochs}) > 1


def test_pixels_depend_only_on_the_seed():
    mask = torch.zeros(2, 1, 6, 6)
    mask[0, 0, 1:5, 1:5] = 1  # 16 pixels
    mask[1, 0, 0, :3] = 1  # 3 pixels: padded with invalid pixels
    seeds = [pixel_seed(0, "synthetic", 4, p) for p in (8, 9)]
    assert seeds[0] != seeds[1] and all(0 <= s < 2**63 for s in seeds)
    pixels, valid = sample_batch_pixels(mask, 8, seeds)
    assert pixels.shape == valid.shape == (2, 8)
    assert valid.sum(1).tolist() == [8, 3]
    # The second sample alone draws the same pixels as inside the batch.
    alone, ok = sample_batch_pixels(mask[1:], 8, seeds[1:])
    assert torch.equal(alone[0, :3], pixels[1, :3]) and bool(ok[0].all())
