"""Tests of network/model/flops.py: parameter counts and the FLOP estimate against ``FlopCounterMode``."""

import pytest
import torch
from torch.nn.attention import SDPBackend, sdpa_kernel
from torch.utils.flop_counter import FlopCounterMode

from network.config import get_config
from network.model.flops import count_parameters, estimate_flops
from network.model.polar_model import PolarInverseModel
from tests.helpers import toy_inputs, toy_model


class TestCost:
    def test_paper_parameter_counts(self):
        with torch.device("meta"):
            model = PolarInverseModel(get_config("paper"))
        # ViT-S/8 with a 24 x 24 grid and 2 input channels (LINO-UniPS: 21.77 M with a 32 x 32 grid and 3 channels).
        assert 21.0e6 < count_parameters(model.tokenizer) < 22.2e6
        assert 28.0e6 < count_parameters(model.interleave) < 29.0e6  # LINO-UniPS: 28.4 M for K = 4
        assert 80e6 < count_parameters(model) < 100e6

    @pytest.mark.parametrize(("dense", "cross"), [(False, "token"), (True, "token"), (False, "global")])
    def test_flop_estimate_matches_flop_counter(self, dense, cross):
        # Exact: the analytic count covers matmuls, convolutions and attention products, which is what
        # FlopCounterMode counts (attention through the math SDPA backend, which it sees as bmm).
        model = toy_model(cross_observation=cross).train(not dense)
        maps, mask = toy_inputs()
        # (FlopCounterMode's module tracking fails under no_grad in torch 2.13, so gradients stay on.)
        with sdpa_kernel(SDPBackend.MATH), FlopCounterMode(display=False) as counter:
            model(maps, mask)
        est = estimate_flops(model.config, masked_pixels=int(mask.sum()))
        assert counter.get_total_flops() == est["dense" if dense else "train"]

    def test_small_training_forward_flops_match_estimate(self):
        # The cost of the small config's training forward at its full input size, counted (not timed: speed targets
        # live in headless/bench.py network). Every pixel is masked, so the decoder sees train_pixels of them.
        model = PolarInverseModel(get_config("small")).train()
        size = model.config.image_size
        maps, mask = torch.rand(1, 9, size, size), torch.ones(1, 1, size, size)
        with sdpa_kernel(SDPBackend.MATH), FlopCounterMode(display=False) as counter:
            out = model(maps, mask)
        est = estimate_flops(model.config, masked_pixels=size * size)
        assert size == 384 and est["decoder_train"] < est["decoder_dense"]
        assert counter.get_total_flops() == est["train"]
        assert out["normal"].shape == (1, 3, model.config.train_pixels)
