"""Tests of network/config.py: presets, overrides, the dict round trip, errors."""

import json

import pytest

from network.config import CONFIGS, ModelConfig, get_config


class TestConfig:
    def test_presets_and_overrides(self):
        assert set(CONFIGS) == {"toy", "small", "medium", "paper"}
        paper = get_config("paper")
        assert (paper.image_size, paper.canonical_size, paper.patch_size) == (384, 192, 8)
        assert (paper.embed_dim, paper.depth, paper.heads, paper.registers) == (384, 12, 6, 4)
        assert (paper.interleave_iters, paper.dpt_dim, paper.agg_dim, paper.train_pixels) == (4, 256, 384, 2048)
        assert get_config("toy", train_pixels=8).train_pixels == 8
        assert CONFIGS["toy"].train_pixels == 64  # presets are not modified

    def test_dict_round_trip_through_json(self):
        for cfg in CONFIGS.values():
            data = json.loads(json.dumps(cfg.to_dict()))
            assert ModelConfig.from_dict(data) == cfg

    def test_errors(self):
        with pytest.raises(ValueError, match="Unknown model config 'huge'"):
            get_config("huge")
        with pytest.raises(ValueError, match="Unknown ModelConfig keys"):
            get_config("toy", depht=3)
        with pytest.raises(ValueError, match="Unknown ModelConfig keys"):
            ModelConfig.from_dict({"image_size": 64, "colour": 1})
        with pytest.raises(ValueError, match="multiple of patch_size"):
            get_config("toy", canonical_size=30)
        with pytest.raises(ValueError, match="embed_dim / heads"):
            get_config("toy", heads=3)
        with pytest.raises(ValueError, match="cross_observation"):
            get_config("toy", cross_observation="all")
        with pytest.raises(ValueError, match="positive int"):
            get_config("toy", train_pixels=0)


def test_medium_preset_sits_between_small_and_paper_and_trains():
    import torch

    from network.model import PolarInverseModel
    from network.model.layers import skip_init

    with torch.device("meta"):  # sizes only: no memory, no initialisation cost
        counts = {n: sum(p.numel() for p in PolarInverseModel(get_config(n)).parameters()) for n in CONFIGS}
    assert counts["small"] < counts["medium"] < counts["paper"]
    assert 10e6 < 2 * counts["medium"] < 100e6  # its bf16 weights: tens of MB
    with skip_init():  # the preset's layers (fewer decoded pixels); a plain normal fill is much faster than its init
        model = PolarInverseModel(get_config("medium", train_pixels=64))
    gen = torch.Generator().manual_seed(0)
    with torch.no_grad():
        for p in model.parameters():
            p.normal_(0.0, 0.05, generator=gen)
    maps, mask = torch.rand(1, 9, 48, 48), torch.ones(1, 1, 48, 48)
    mask[..., :6, :] = 0
    out = model(maps, mask)
    assert out["normal"].shape == (1, 3, 64) and all(torch.isfinite(v).all() for v in out.values())
    sum(v.float().mean() for v in out.values()).backward()
    grads = [p.grad for p in model.parameters() if p.requires_grad]
    assert all(g is not None and torch.isfinite(g).all() for g in grads)
    assert sum(float(g.abs().sum()) > 0 for g in grads) > 0.9 * len(grads)
