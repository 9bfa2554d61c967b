"""Tests of network/losses.py: the synthetic loss by hand."""

import pytest
import torch

from network import losses


def test_loss_matches_hand_computation_and_skips_zero_weights():
    pred = {"normal": torch.zeros(1, 3, 2), "albedo": torch.ones(1, 3, 2), "roughness": torch.zeros(1, 1, 2),
            "metallic": torch.zeros(1, 1, 2)}  # fmt: skip
    tgt = {"normal": torch.ones(1, 3, 2), "albedo": torch.ones(1, 3, 2) * 0.5, "roughness": torch.ones(1, 1, 2),
           "metallic": torch.zeros(1, 1, 2)}  # fmt: skip
    valid = torch.tensor([[[1.0, 0.0]]])
    w = losses.LossWeights(normal=1.0, albedo=2.0, roughness=1.0, metallic=0.0, chromaticity=0.0)
    loss, parts = losses.synthetic_loss(pred, tgt, valid, w)
    # normal: 3 * 1^2 = 3; albedo: 3 * 0.5^2 = 0.75 (x2); roughness: 1; one valid pixel.
    assert float(loss) == pytest.approx(3 + 2 * 0.75 + 1)
    assert set(parts) == {"normal", "albedo", "roughness"}
