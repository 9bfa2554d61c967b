"""network.bench.model: the toy model's timings, decoded-pixel counts and stride errors."""

import pytest

pytest.importorskip("torch")

from network.bench import model  # noqa: E402


def test_smooth_input_mask_fraction():
    maps, mask = model.smooth_input(64, 0.5)
    assert maps.shape == (1, 9, 64, 64) and mask.shape == (1, 1, 64, 64)
    assert abs(float(mask.mean()) - 0.5) < 0.02
    assert 0.1 <= float(maps.min()) and float(maps.max()) <= 0.5


def test_toy_inference_entries():
    result = model.run(configs=("toy",), strides=(2,), train=False, capture=None)
    toy = result["configs"]["toy"]
    assert set(toy["inference"]) == {"stride_1", "stride_2"}  # stride 1 is always added
    s1, s2 = toy["inference"]["stride_1"], toy["inference"]["stride_2"]
    assert s1["decoded_pixels"] == toy["masked_pixels"] and s2["decoded_pixels"] < s1["decoded_pixels"]
    assert s1["max_abs_difference_to_reference"] < 1e-3
    assert s2["error_vs_stride_1"]["normal_deg_mean"] >= 0
    assert toy["encode"]["warmup_runs"] == 1 and toy["encode"]["repeats"] == 1
    assert "train_step_seconds" not in toy and "predict" not in result
    assert result["timing_rule"] and result["machine"]["torch"]


def test_bad_settings():
    with pytest.raises(ValueError, match="mask_fraction"):
        model.ModelBench(mask_fraction=0.0)
