"""network/distance_sensitivity.py: a light-blind model's rows are equal, a light model's move with the distance."""

from __future__ import annotations

import pytest
import torch

from network.config import get_config
from network.distance_sensitivity import distance_sensitivity, sensitivity_markdown
from network.model import PolarInverseModel

STATS = {"format": "pdir-train-stats/1", "albedo": [0.4, 0.35, 0.3], "roughness": 0.42, "metallic": 0.3}
CKPT = {"inputs": "full", "input_scale": "calibrated"}


pytestmark = pytest.mark.usefixtures("torch_one_thread")  # tests/conftest.py


@pytest.mark.mitsuba
def test_blind_rows_are_equal_and_light_rows_move(tiny_dataset):
    torch.manual_seed(0)
    blind = PolarInverseModel(get_config("toy")).eval()
    result = distance_sensitivity(blind, CKPT, tiny_dataset, STATS, [0.2], limit=2)
    assert result["errors"] == [0.0, 0.2] and result["scenes"] == 2 and result["light_input"] is False
    assert result["rows"]["0.2"]["delta_albedo_psnr"]["mean"] == 0.0
    assert "light-blind" in sensitivity_markdown(result)
    light = PolarInverseModel(get_config("toy", light_input=True)).eval()
    light.load_state_dict(blind.state_dict(), strict=False)
    with torch.no_grad():
        light.decoder.chi.weight.normal_(0, 1.0)
    moved = distance_sensitivity(light, CKPT, tiny_dataset, STATS, [-0.2], limit=2)
    assert abs(moved["rows"]["-0.2"]["delta_albedo_psnr"]["mean"]) > 1e-4
    with pytest.raises(ValueError, match="errors must be > -1"):
        distance_sensitivity(blind, CKPT, tiny_dataset, STATS, [-1.0])


@pytest.mark.mitsuba
def test_refinement_is_told_the_scaled_distance(tiny_dataset, monkeypatch):
    """With refine, the refinement fits at the median true depth times 1 + e (a tape measure's error)."""
    import numpy as np

    from network import refine as refine_mod
    from pbrdf.data import sample as psample

    told = []
    real = refine_mod.refine

    def spy(pred, maps, intrinsics, rig, radiance, distance, **kw):
        told.append(distance)
        return real(pred, maps, intrinsics, rig, radiance, distance, **kw)

    monkeypatch.setattr(refine_mod, "refine", spy)
    torch.manual_seed(0)
    blind = PolarInverseModel(get_config("toy")).eval()
    result = distance_sensitivity(blind, CKPT, tiny_dataset, STATS, [0.2], limit=1, refine=True)
    assert result["refine"] is True and "+ refinement" in sensitivity_markdown(result)
    sample, _ = psample.read_sample(tiny_dataset, 0, keys=("depth", "object"))
    region = (sample["object"] >= 0) & (sample["depth"] > 0)
    truth = float(np.median(sample["depth"][region]))
    assert sorted(told) == pytest.approx([truth, truth * 1.2], rel=1e-6)
