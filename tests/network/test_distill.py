"""Distillation from a frozen teacher: the loss, its checks, and what it does to a real fine-tune."""

from __future__ import annotations

import pytest
import torch

from network.checkpoint import load_checkpoint
from network.data import SampleDataset
from network.distill import Teacher, check_distill, distill_loss
from network.train import train
from tests.helpers import toy_train_config

pytestmark = pytest.mark.usefixtures("torch_one_thread")  # tests/conftest.py


def test_distill_loss_is_the_masked_mean_square_and_spares_the_teacher():
    pred = {"metallic": torch.tensor([[[0.5, 0.2, 0.9]]], requires_grad=True),
            "roughness": torch.tensor([[[0.1, 0.1, 0.1]]])}  # fmt: skip
    teacher = {"metallic": torch.tensor([[[0.1, 0.2, 0.0]]], requires_grad=True),
               "roughness": torch.tensor([[[0.6, 0.6, 0.6]]])}  # fmt: skip
    valid = torch.tensor([[[1.0, 1.0, 0.0]]])  # the third pixel (error 0.9) is padding
    loss = distill_loss(pred, teacher, valid, ("metallic",))
    assert float(loss.detach()) == pytest.approx((0.4**2 + 0.0) / 2, abs=1e-7)
    loss.backward()
    assert teacher["metallic"].grad is None  # a target, not a second student
    assert pred["metallic"].grad[0, 0, 2] == 0.0
    both = distill_loss(pred, teacher, valid, ("metallic", "roughness"))
    assert float(both) == pytest.approx(0.08 + 0.25, abs=1e-6)
    assert float(distill_loss(pred, teacher, torch.zeros_like(valid), ("metallic",))) == 0.0


def test_distill_settings_are_checked(tmp_path):
    check_distill(None, 0.0, ("metallic",))  # off
    with pytest.raises(ValueError, match="needs distill_from"):
        check_distill(None, 1.0, ("metallic",))
    with pytest.raises(ValueError, match="distill_keys"):
        check_distill(tmp_path, 1.0, ("gloss",))
    with pytest.raises(ValueError, match="distill_weight"):
        check_distill(tmp_path, float("nan"), ("metallic",))


@pytest.mark.mitsuba
def test_distillation_keeps_the_fine_tuned_metallic_at_the_teachers(tiny_dataset, tmp_path):
    """Fine-tuning away from a teacher: with the term, metallic stays near the teacher's; step 0 is unchanged."""
    teacher = tmp_path / "teacher"
    train(toy_train_config(tiny_dataset, teacher, steps=2, checkpoint_every=2), progress=False)
    common = {"steps": 8, "seed": 1, "lr": 1e-2, "init_from": teacher / "model.pt"}
    free = train(toy_train_config(tiny_dataset, tmp_path / "free", **common), progress=False)
    held = train(
        toy_train_config(tiny_dataset, tmp_path / "held", **common, distill_from=teacher / "model.pt",
                         distill_weight=100.0),
        progress=False,
    )  # fmt: skip
    assert held[0] == free[0]  # the student starts as the teacher: the term is exactly 0 at step 0
    assert held[1:] != free[1:]

    ds = SampleDataset(tiny_dataset, size=64, input_scale="calibrated")
    t = Teacher(teacher / "model.pt", "full", "calibrated", torch.device("cpu"))

    def gap(run):
        model, _ = load_checkpoint(tmp_path / run / "model.pt")
        total = 0.0
        for i in range(len(ds)):
            item = ds[i]
            pixels = torch.arange(0, 64 * 64, 7)[None]
            valid = item["mask"].reshape(1, -1)[:, pixels[0]] > 0
            with torch.no_grad():
                mine = model.decode_pixels(model.encode(item["maps"][None], item["mask"][None]), item["maps"][None],
                                           pixels, valid)  # fmt: skip
            theirs = t(item["maps"][None], item["mask"][None], pixels, valid, None)
            total += float(((mine["metallic"] - theirs["metallic"]) ** 2)[valid[:, None]].mean())
        return total / len(ds)

    assert gap("held") < 0.25 * gap("free")
    with pytest.raises(ValueError, match="distill_from checkpoint was trained with input_scale='calibrated'"):
        Teacher(teacher / "model.pt", "full", "exposure-invariant", torch.device("cpu"))
