"""Tests of network/config.py: presets, overrides, the dict round trip, errors."""

import json

import pytest

from network.config import CONFIGS, ModelConfig, get_config


class TestConfig:
    def test_presets_and_overrides(self):
        assert set(CONFIGS) == {"toy", "small", "paper"}
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
