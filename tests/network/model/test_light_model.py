"""The light input in the model: off by default, zero-initialised, exactly the light-blind model at the start."""

from __future__ import annotations

import pytest
import torch

from network.checkpoint import CHECKPOINT_FORMAT, init_from_checkpoint, load_checkpoint, save_checkpoint
from network.config import ModelConfig, get_config
from network.model import PolarInverseModel


def _inputs(seed: int = 0, size: int = 32, batch: int = 2):
    g = torch.Generator().manual_seed(seed)
    maps = torch.rand(batch, 9, size, size, generator=g)
    mask = torch.zeros(batch, 1, size, size)
    mask[:, :, 4:20, 6:26] = 1
    light = torch.randn(batch, 9, size, size, generator=g)
    return maps, mask, light


def _blind_checkpoint(tmp_path):
    torch.manual_seed(3)
    blind = PolarInverseModel(get_config("toy")).eval()
    path = tmp_path / "model.pt"
    save_checkpoint(path, {"format": CHECKPOINT_FORMAT, "config": blind.config.to_dict(), "model": blind.state_dict()})
    return blind, path


def test_light_input_is_off_by_default_and_absent_from_old_dicts():
    cfg = get_config("toy")
    assert cfg.light_input is False and "light_input" not in cfg.to_dict()
    on = get_config("toy", light_input=True)
    assert on.to_dict()["light_input"] is True and ModelConfig.from_dict(on.to_dict()) == on
    names = {n for n, _ in PolarInverseModel(cfg).named_parameters()}
    assert not any("light" in n or "chi" in n for n in names)
    with pytest.raises(ValueError, match="light_input must be a bool"):
        get_config("toy", light_input=1)


def test_init_from_a_blind_checkpoint_gives_exactly_its_outputs(tmp_path):
    blind, path = _blind_checkpoint(tmp_path)
    model = PolarInverseModel(get_config("toy", light_input=True)).eval()
    init_from_checkpoint(model, path)
    maps, mask, light = _inputs()
    with torch.no_grad():
        want = blind(maps, mask)
        got = model(maps, mask, light=light)
        pix = torch.tensor([[4 * 32 + 6, 10 * 32 + 20], [19 * 32 + 7, 5 * 32 + 25]])
        want_p = blind(maps, mask, pixels=pix)
        got_p = model(maps, mask, pixels=pix, light=light)
    for k in ("normal", "albedo", "roughness", "metallic"):
        assert torch.equal(got[k], want[k]), k
        assert torch.equal(got_p[k], want_p[k]), k


def test_light_changes_the_output_once_its_weights_move(tmp_path):
    """The new weights get gradients, and after a change the prediction depends on the light (dense and reference)."""
    _, path = _blind_checkpoint(tmp_path)
    model = PolarInverseModel(get_config("toy", light_input=True))
    init_from_checkpoint(model, path)
    maps, mask, light = _inputs(batch=1)
    model.train()
    out = model(maps, mask, light=light, generator=torch.Generator().manual_seed(0))
    out["albedo"].sum().backward()
    assert model.light_embed.weight.grad.abs().sum() > 0 and model.decoder.chi.weight.grad.abs().sum() > 0
    with torch.no_grad():
        model.light_embed.weight.normal_(0, 0.05)
        model.decoder.chi.weight.normal_(0, 0.05)
    model.eval()
    with torch.no_grad():
        a = model(maps, mask, light=light)["albedo"]
        b = model(maps, mask, light=2 * light)["albedo"]
        feats = model.encode(maps, mask, light)
        ref = model.decode_dense_reference(feats, maps, mask, light=light)["albedo"]
    assert (a - b).abs().max() > 1e-4
    torch.testing.assert_close(a, ref, atol=1e-5, rtol=1e-4)


def test_light_model_refuses_missing_or_misshapen_light():
    model = PolarInverseModel(get_config("toy", light_input=True)).eval()
    maps, mask, light = _inputs()
    with pytest.raises(ValueError, match=r"light must have shape \(2, 9, 32, 32\)"):
        model(maps, mask)
    with pytest.raises(ValueError, match="light must have shape"):
        model(maps, mask, light=light[:, :3])


def test_init_from_refuses_another_architecture(tmp_path):
    _, path = _blind_checkpoint(tmp_path)
    model = PolarInverseModel(get_config("toy", light_input=True, agg_dim=64))
    with pytest.raises(ValueError, match="model config differs"):
        init_from_checkpoint(model, path)


def test_a_light_checkpoint_round_trips(tmp_path):
    model = PolarInverseModel(get_config("toy", light_input=True)).eval()
    path = tmp_path / "light.pt"
    save_checkpoint(path, {"format": CHECKPOINT_FORMAT, "config": model.config.to_dict(), "model": model.state_dict()})
    loaded, _ = load_checkpoint(path)
    assert loaded.config.light_input is True
    assert torch.equal(loaded.decoder.chi.weight, model.decoder.chi.weight)
