"""Tests of network/model/pretrained.py: loading tokenizer weights, DINOv2 conversions, errors."""

import pytest
import torch

from network.model.pretrained import load_pretrained_vit
from network.model.tokenizer import ViTTokenizer
from tests.helpers import toy_model


class TestPretrained:
    def test_round_trip(self, tmp_path):
        source = toy_model(seed=1)
        path = tmp_path / "vit.pt"
        torch.save(source.tokenizer.state_dict(), path)
        target = toy_model(seed=2)
        inp = torch.rand(3, 2, 32, 32)
        with torch.no_grad():
            assert not torch.equal(target.tokenizer(inp)[0], source.tokenizer(inp)[0])
            report = load_pretrained_vit(target, path)
            assert report.ok and not report.adapted
            assert len(report.loaded) == len(source.tokenizer.state_dict())
            assert torch.equal(target.tokenizer(inp)[0], source.tokenizer(inp)[0])

    def test_wrong_keys(self, tmp_path):
        state = toy_model().tokenizer.state_dict()
        state["blocks.0.attn.qkv_weight"] = state.pop("blocks.0.attn.qkv.weight")
        path = tmp_path / "bad.pt"
        torch.save(state, path)
        target = toy_model(seed=3)
        before = target.tokenizer.blocks[0].norm1.weight.clone()
        with pytest.raises(
            ValueError, match=r"missing 1: blocks\.0\.attn\.qkv\.weight.*unexpected 1: blocks\.0\.attn\.qkv_weight"
        ):
            load_pretrained_vit(target, path)
        assert torch.equal(target.tokenizer.blocks[0].norm1.weight, before)  # nothing copied
        report = load_pretrained_vit(target, path, strict=False)
        assert report.missing == ["blocks.0.attn.qkv.weight"] and report.unexpected == ["blocks.0.attn.qkv_weight"]

    def test_shape_mismatch(self, tmp_path):
        other = ViTTokenizer(patch_size=4, dim=32, depth=1, heads=2, registers=2, grid=4)
        path = tmp_path / "p4.pt"
        torch.save(other.state_dict(), path)
        with pytest.raises(ValueError, match=r"shape mismatch 1.*patch_embed\.proj\.weight"):
            load_pretrained_vit(toy_model(), path)

    def test_dinov2_style_conversions(self, tmp_path):
        # A DINOv2-like file: RGB patch embedding, another position grid, and a mask_token.
        rgb = ViTTokenizer(patch_size=8, dim=32, depth=1, heads=2, registers=2, grid=7, in_chans=3)
        state = rgb.state_dict()
        state["mask_token"] = torch.zeros(1, 32)
        path = tmp_path / "dinov2_like.pt"
        torch.save(state, path)
        model = toy_model()
        report = load_pretrained_vit(model, path)
        assert sorted(report.adapted) == ["patch_embed.proj.weight", "pos_embed"] and report.ignored == ["mask_token"]
        w = model.tokenizer.patch_embed.proj.weight
        torch.testing.assert_close(w[:, 0], state["patch_embed.proj.weight"].sum(1))
        assert bool((w[:, 1] == 0).all())
        # A grey map replicated to RGB gives the same tokens in both models (mask channel all zero here).
        grey = torch.rand(2, 1, 32, 32)
        with torch.no_grad():
            ours = model.tokenizer(torch.cat([grey, torch.zeros_like(grey)], 1))[0]
            theirs = rgb(grey.expand(-1, 3, -1, -1))[0]
        torch.testing.assert_close(ours, theirs, rtol=1e-4, atol=1e-4)

    def test_unreadable_files(self, tmp_path):
        with pytest.raises(OSError, match="Cannot read"):
            load_pretrained_vit(toy_model(), tmp_path / "absent.pt")
        path = tmp_path / "list.pt"
        torch.save([torch.zeros(1)], path)
        with pytest.raises(ValueError, match="flat dict of tensors"):
            load_pretrained_vit(toy_model(), path)
