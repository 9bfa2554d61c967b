"""Training with the light input: the dataset's light channels and distance, fine-tuning from a blind model."""

from __future__ import annotations

import numpy as np
import pytest

from network.checkpoint import load_checkpoint
from network.data import SampleDataset
from network.light_input import light_channels
from network.train import train
from pbrdf.data import sample as psample
from pbrdf.data.sample import sample_intrinsics
from pbrdf.sensor.rig import Rig
from tests.helpers import toy_train_config

pytestmark = pytest.mark.usefixtures("torch_one_thread")  # tests/conftest.py


@pytest.mark.mitsuba
def test_dataset_light_is_the_display_at_the_median_depth(tiny_dataset):
    ds = SampleDataset(tiny_dataset, size=16, input_scale="calibrated", light_input=True)
    item = ds[0]
    sample, meta = psample.read_sample(tiny_dataset, ds.indices[0], keys=("mask", "depth"))
    d = float(np.median(sample["depth"][sample["mask"]]))
    assert float(item["distance"]) == pytest.approx(d, rel=1e-6)
    assert 0.2 < d < 3.0
    k = sample_intrinsics(meta, sample["mask"].shape, "s") * np.array([[0.5], [0.5], [1]])  # 32 -> 16 px
    rig = Rig.from_dict(meta["rig"]) if "rig" in meta else Rig()
    np.testing.assert_allclose(item["light"].numpy(), light_channels(rig, k, (16, 16), d), rtol=1e-5, atol=1e-7)
    assert "light" not in SampleDataset(tiny_dataset, size=16)[0]


@pytest.mark.mitsuba
def test_fine_tuning_a_light_model_starts_at_the_blind_one(tiny_dataset, tmp_path):
    """Step 0 of a light_input run initialised from a blind model has exactly the blind model's loss."""
    blind = tmp_path / "blind"
    train(toy_train_config(tiny_dataset, blind, steps=2, checkpoint_every=2), progress=False)
    cont = train(
        toy_train_config(tiny_dataset, tmp_path / "cont", steps=1, seed=1, init_from=blind / "model.pt"), progress=False
    )
    light = train(
        toy_train_config(tiny_dataset, tmp_path / "light", steps=3, seed=1, init_from=blind / "model.pt",
             overrides={"light_input": True}),
        progress=False,
    )  # fmt: skip
    assert light[0] == cont[0]  # same weights, same pixels: the zero light weights change nothing at first
    model, ckpt = load_checkpoint(tmp_path / "light" / "model.pt")
    assert model.config.light_input is True and ckpt["config"]["light_input"] is True
    assert model.decoder.chi.weight.abs().sum() > 0  # and they train
    with pytest.raises(ValueError, match="init_from checkpoint was trained with input_scale='calibrated'"):
        train(toy_train_config(tiny_dataset, tmp_path / "x", steps=1, init_from=blind / "model.pt",
                   input_scale="exposure-invariant"), progress=False)  # fmt: skip
