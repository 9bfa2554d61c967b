"""network.bench.model: the toy model's timings and decoded-pixel counts, the training forward with gradients, and
the stride error of the shipped model on real-path input."""

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from network.bench import model  # noqa: E402
from network.config import get_config  # noqa: E402
from network.model.polar_model import PolarInverseModel  # noqa: E402

needs_shipped = pytest.mark.skipif(
    not model.SHIPPED_CHECKPOINT.is_file(), reason="models/small/model.pt not trained in this tree"
)


@pytest.fixture(autouse=True)
def _one_thread():
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # a shared 2-core machine
    yield
    torch.set_num_threads(threads)


def test_smooth_input_mask_fraction():
    maps, mask = model.smooth_input(64, 0.5)
    assert maps.shape == (1, 9, 64, 64) and mask.shape == (1, 1, 64, 64)
    assert abs(float(mask.mean()) - 0.5) < 0.02
    assert 0.1 <= float(maps.min()) and float(maps.max()) <= 0.5


def test_toy_inference_entries():
    result = model.run(configs=("toy",), strides=(2,), train=False, checkpoint=None)
    toy = result["configs"]["toy"]
    assert set(toy["inference"]) == {"stride_1", "stride_2"}  # stride 1 is always added
    s1, s2 = toy["inference"]["stride_1"], toy["inference"]["stride_2"]
    assert s1["decoded_pixels"] == toy["masked_pixels"] and s2["decoded_pixels"] < s1["decoded_pixels"]
    assert s1["max_abs_difference_to_reference"] < 1e-3
    # A randomly initialised model's stride error says nothing: it is measured with the shipped model only.
    assert "error_vs_stride_1" not in s2 and "randomly initialised" in result["input"]
    assert toy["encode"]["warmup_runs"] == 1 and toy["encode"]["repeats"] == 1
    assert "train_step_seconds" not in toy and "predict" not in result
    assert result["timing_rule"] and result["machine"]["torch"]


def test_training_forward_is_timed_with_gradients():
    torch.manual_seed(0)
    net = PolarInverseModel(get_config("toy"))
    grad_on = []
    net.register_forward_pre_hook(lambda *_: grad_on.append(torch.is_grad_enabled()))
    maps, mask = model.smooth_input(64, 0.5)
    entry = model._train_entry(net, maps, mask, model.ModelBench(repeat=2, warmup=1), 64)
    fwd = entry["train_forward"]
    # Three forwards timed as the training forward, then three training steps, all with autograd on as in training.
    assert grad_on == [True] * 6 and fwd["grad_enabled"] is True
    assert fwd["what"].startswith("training-mode forward with gradients enabled") and "no backward" in fwd["what"]
    assert fwd["repeats"] == 2 and fwd["warmup_runs"] == 1 and entry["train_forward_seconds"] == fwd["seconds_median"]


@needs_shipped
def test_stride_error_of_the_shipped_model_on_real_input():
    from network.checkpoint import load_checkpoint
    from network.infer import load_input, predict
    from network.metrics import normal_angle_deg

    result = model.run(configs=("toy",), strides=(2, 4), train=False, reference=False, warmup=0)
    pred = result["predict"]
    assert pred["checkpoint"] == str(model.SHIPPED_CHECKPOINT) and pred["capture"] == str(model.EXAMPLE_CAPTURE)
    assert set(pred) >= {"stride_1", "stride_2", "stride_4"} and "error_vs_stride_1" not in pred["stride_1"]
    e2, e4 = (pred[f"stride_{s}"]["error_vs_stride_1"] for s in (2, 4))
    # The same numbers recomputed here from the shipped model on the real-capture path.
    net, ckpt = load_checkpoint(model.SHIPPED_CHECKPOINT)
    inp = load_input(model.EXAMPLE_CAPTURE)
    maps, mask = inp.maps, inp.mask
    assert pred["masked_pixels"] == int(mask.sum()) > 1000
    how = {
        "inputs": ckpt.get("inputs", "full"),
        "input_scale": ckpt.get("input_scale", "exposure-invariant"),
        "radiance": inp.radiance,
    }
    one, two = (predict(net, maps, mask, stride=s, **how) for s in (1, 2))
    angle = normal_angle_deg(one["normal"], two["normal"])[mask]
    assert e2["normal_deg_mean"] == pytest.approx(float(angle.mean()), rel=1e-4, abs=1e-4)
    assert e2["albedo_mae"] == pytest.approx(float(np.abs(one["albedo"] - two["albedo"])[mask].mean()), abs=1e-5)
    # A trained model on real input: an error that grows with the stride (measured 0.2-0.7 and 0.6-1.9 deg).
    p2, p4 = (pred[f"stride_{s}_plain"]["error_vs_stride_1"] for s in (2, 4))
    assert 0.01 < p2["normal_deg_mean"] < p4["normal_deg_mean"] < 10.0
    # Edge-aware (default) strides: the refinement bounds the tail below the plain interpolation's.
    assert e2["normal_deg_p99"] <= p2["normal_deg_p99"] and e4["normal_deg_p99"] <= p4["normal_deg_p99"]
    assert e2["normal_deg_mean"] <= e2["normal_deg_p99"] <= e2["normal_deg_max"]


def test_bad_settings():
    with pytest.raises(ValueError, match="mask_fraction"):
        model.ModelBench(mask_fraction=0.0)
